"""Stereo calibration against synthetic truth, and the corner-order traps between cameras."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from calibration.boards import BoardSpec, Detection, parse_board
from calibration.stereo import StereoPair, align_pair, calibrate_stereo
from calibration.synthetic import project_board, random_board_poses
from calibration.triangulate import StereoRig


def _projected_pairs(
    rig: StereoRig, board: BoardSpec, count: int, noise_px: float, seed: int
) -> list[StereoPair]:
    rng = np.random.default_rng(seed)
    cams = [(rig.left, np.eye(4)), (rig.right, rig.right_T_left)]
    pairs = []
    for i, left_T_board in enumerate(random_board_poses(board, cams, count, rng)):
        dl = project_board(board, rig.left, left_T_board, noise_px, rng)
        dr = project_board(board, rig.right, rig.right_T_left @ left_T_board, noise_px, rng)
        pairs.append(StereoPair(f"{i:02d}", dl, dr))
    return pairs


def _rotation_angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def test_cli_stereo_on_rendered_images(rendered_stereo: Any, tmp_path: Path, run_cli: Any) -> None:
    """Rendered 640×480 pairs, real detection: baseline within 0.5%, focal within 0.5%."""
    code, stdout, stderr = run_cli(
        "stereo",
        "--left",
        str(rendered_stereo.left_dir),
        "--right",
        str(rendered_stereo.right_dir),
        "--board",
        "chessboard:9x6:0.025",
        "--out",
        str(tmp_path),
        "--json",
    )
    assert code == 0, stderr
    summary = json.loads(stdout)
    truth: StereoRig = rendered_stereo.rig
    assert summary["baseline"] == pytest.approx(truth.baseline, rel=0.005)  # metres
    assert summary["left"]["fx"] == pytest.approx(truth.left.fx, rel=0.005)
    assert summary["right"]["fy"] == pytest.approx(truth.right.fy, rel=0.005)
    assert summary["views_used"] == 14 and summary["views_rejected"] == 0
    rig = StereoRig.load(tmp_path / "stereo.yaml")
    assert _rotation_angle_deg(rig.R.T @ truth.R) < 0.05
    np.testing.assert_allclose(rig.T, truth.T, atol=0.0005)
    assert summary["epipolar_rms_px"] < 0.1
    assert summary["cross_validation"]["baseline_pct"] < 0.5
    for name in (
        "stereo.yaml",
        "left.yaml",
        "right.yaml",
        "left_camera_info.yaml",
        "right_camera_info.yaml",
        "report.md",
        "report.png",
        "summary.json",
    ):
        assert (tmp_path / name).is_file(), name


def test_point_symmetric_board_flipped_between_cameras(rig: StereoRig) -> None:
    """An 8×6 board looks the same turned by 180°, so a corner finder may start counting at
    opposite ends in the two images. Half the right views are flipped here; the calibration must
    still find the true baseline and reject nothing."""
    board = parse_board("chessboard:8x6:0.025")
    pairs = _projected_pairs(rig, board, 12, 0.15, seed=11)
    flipped = []
    for i, p in enumerate(pairs):
        assert p.right is not None
        right = p.right.reversed() if i % 2 else p.right
        flipped.append(StereoPair(p.name, p.left, right))
    res = calibrate_stereo(flipped, board, (640, 480))
    assert res.views_rejected == 0
    assert res.rig.baseline == pytest.approx(rig.baseline, rel=0.005)
    assert res.rms_px < 0.3


def test_align_pair_keeps_common_charuco_ids() -> None:
    board = parse_board("charuco:7x5:0.03:0.022:DICT_4X4_50")
    ids = np.arange(board.corner_count, dtype=np.int32)
    obj = board.object_points()
    pts = obj[:, :2] * 1000
    left = Detection(pts.astype(np.float32), obj, ids)
    right = Detection(pts[3:].astype(np.float32) + 5, obj[3:], ids[3:])
    a, b = align_pair(left, right, board)
    np.testing.assert_array_equal(a.ids, b.ids)
    np.testing.assert_array_equal(a.ids, ids[3:])
    np.testing.assert_allclose(b.image_points - a.image_points, 5.0)


def test_charuco_partial_views_calibrate(rig: StereoRig) -> None:
    """ChArUco views where each camera misses different corners still pair up by id."""
    board = parse_board("charuco:9x7:0.03:0.022:DICT_4X4_100")
    pairs = _projected_pairs(rig, board, 10, 0.15, seed=12)
    rng = np.random.default_rng(0)
    partial = []
    for p in pairs:
        assert p.left is not None and p.right is not None
        keep_l = np.sort(rng.choice(board.corner_count, 40, replace=False))
        keep_r = np.sort(rng.choice(board.corner_count, 40, replace=False))
        partial.append(StereoPair(p.name, p.left.subset(keep_l), p.right.subset(keep_r)))
    res = calibrate_stereo(partial, board, (640, 480))
    assert res.rig.baseline == pytest.approx(rig.baseline, rel=0.005)


def test_refine_intrinsics_and_missing_boards(rig: StereoRig, board: BoardSpec) -> None:
    pairs = _projected_pairs(rig, board, 10, 0.15, seed=13)
    pairs.append(StereoPair("no_right", pairs[0].left, None))
    res = calibrate_stereo(pairs, board, (640, 480), refine_intrinsics=True)
    reasons = {p.name: p.reason for p in res.pairs if not p.used}
    assert reasons == {"no_right": "no board in the right image"}
    # stereoCalibrate moved the intrinsics (refined), and they stay near the truth
    assert res.rig.left.fx != res.left.camera.fx
    assert res.rig.left.fx == pytest.approx(rig.left.fx, rel=0.01)
    assert res.rig.baseline == pytest.approx(rig.baseline, rel=0.005)
    summary = res.summary()
    assert summary["views_used"] == 10 and summary["views_rejected"] == 1
    assert set(summary["left"]) >= {"fx", "fy", "cx", "cy", "rms_px"}
