"""Mono calibration: accuracy against truth, outlier rejection, σ, cross-validation, coverage."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from calibration.boards import BoardSpec
from calibration.dataset import detect_images, list_images
from calibration.errors import BoardNotFoundError, ConfigError, UnknownNameError
from calibration.intrinsics import CalibrationConfig, View, calibrate_camera
from calibration.synthetic import project_board, random_board_poses
from calibration.triangulate import StereoRig


def _projected_views(
    rig: StereoRig, board: BoardSpec, count: int, noise_px: float, seed: int
) -> list[View]:
    rng = np.random.default_rng(seed)
    poses = random_board_poses(board, [(rig.left, np.eye(4))], count, rng)
    views = []
    for i, cam_T_board in enumerate(poses):
        det = project_board(board, rig.left, cam_T_board, noise_px, rng)
        assert det is not None
        views.append(View(f"v{i:02d}", det))
    return views


def test_rendered_images_recover_intrinsics(rendered_stereo: Any, board: BoardSpec) -> None:
    """Real OpenCV detection on rendered images: fx, fy within 0.5%, principal point ~1 px."""
    paths = list_images(rendered_stereo.left_dir)
    detected = detect_images(board, paths)
    views = [View(p.name, d) for p, d in zip(paths, detected.detections, strict=True) if d]
    assert len(views) == len(paths)
    res = calibrate_camera(views, detected.image_size, name="left")
    truth = rendered_stereo.rig.left
    assert res.camera.fx == pytest.approx(truth.fx, rel=0.005)
    assert res.camera.fy == pytest.approx(truth.fy, rel=0.005)
    assert abs(res.camera.cx - truth.cx) < 1.5 and abs(res.camera.cy - truth.cy) < 1.5
    assert res.camera.dist[0] == pytest.approx(truth.dist[0], abs=0.01)
    assert res.rms_px < 0.15
    assert res.views_used == len(paths) and res.views_rejected == 0
    assert not res.warnings
    # σ is reported for every intrinsic and is consistent with the actual error
    assert set(res.std) >= {"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"}
    assert 0 < res.std["fx"] < 2.0
    assert abs(res.camera.fx - truth.fx) < 5 * res.std["fx"] + 0.5


def test_outlier_view_is_rejected_and_named(rig: StereoRig, board: BoardSpec) -> None:
    views = _projected_views(rig, board, 12, 0.1, seed=1)
    bad = views[5].detection
    rng = np.random.default_rng(9)
    corrupted = type(bad)(
        (bad.image_points + rng.normal(0, 2.0, bad.image_points.shape)).astype(np.float32),
        bad.object_points,
        bad.ids,
    )
    views[5] = View("blurred.png", corrupted)
    res = calibrate_camera(views, (640, 480))
    rejected = [v for v in res.views if not v.used]
    assert [v.name for v in rejected] == ["blurred.png"]
    assert "outlier" in rejected[0].reason
    assert res.rms_px < 0.15
    assert res.camera.fx == pytest.approx(rig.left.fx, rel=0.005)
    kept = calibrate_camera(views, (640, 480), CalibrationConfig(reject_outliers=False))
    assert kept.views_rejected == 0 and kept.rms_px > 2 * res.rms_px


def test_high_rms_warns(rig: StereoRig, board: BoardSpec) -> None:
    views = _projected_views(rig, board, 10, 0.9, seed=2)
    res = calibrate_camera(views, (640, 480))
    assert res.rms_px > 0.5
    assert any("above 0.5 px" in w for w in res.warnings)


def test_cross_validation_and_coverage(rig: StereoRig, board: BoardSpec) -> None:
    views = _projected_views(rig, board, 12, 0.2, seed=3)
    res = calibrate_camera(views, (640, 480))
    cv = res.cross_validation
    assert set(cv) == {"fx_px", "fy_px", "cx_px", "cy_px", "fx_pct", "heldout_rms_px"}
    assert cv["fx_pct"] < 3.0  # six views per half at 0.2 px noise
    # the held-out error is measured on views the half never saw: close to, not below, the noise
    assert 0.15 < cv["heldout_rms_px"] < 0.4
    assert res.coverage.shape == (6, 8)
    assert res.coverage.sum() == 12 * board.corner_count
    assert 0 < res.coverage_fraction <= 1
    summary = res.summary()
    for key in ("fx", "fy", "cx", "cy", "rms_px", "views_used", "views_rejected", "sigma"):
        assert key in summary


def test_failed_images_are_listed(rig: StereoRig, board: BoardSpec) -> None:
    views = _projected_views(rig, board, 8, 0.1, seed=4)
    res = calibrate_camera(views, (640, 480), failed=["dark.png"])
    assert res.views_rejected == 1
    assert [v.reason for v in res.views if v.name == "dark.png"] == ["no board"]


def test_too_few_views(rig: StereoRig, board: BoardSpec) -> None:
    views = _projected_views(rig, board, 3, 0.1, seed=5)
    with pytest.raises(BoardNotFoundError, match="only 3 image"):
        calibrate_camera(views, (640, 480))


def test_zero_distortion_model_for_ideal_cameras(board: BoardSpec) -> None:
    """MuJoCo renders an ideal pinhole: the 'none' model recovers it with no distortion."""
    from calibration.camera import CameraModel

    cam = CameraModel.from_fovy(45.0, 640, 480)
    rig_like = StereoRig(cam, cam, np.eye(3), [0.1, 0, 0])
    views = _projected_views(rig_like, board, 8, 0.1, seed=6)
    res = calibrate_camera(views, (640, 480), CalibrationConfig(dist_model="none"))
    assert np.all(res.camera.dist == 0)
    assert abs(res.camera.fx - cam.fx) < 3 * res.std["fx"]


def test_config_validation() -> None:
    with pytest.raises(UnknownNameError, match="valid: k1k2, none, plumb_bob, rational"):
        CalibrationConfig(dist_model="fisheye")
    with pytest.raises(ConfigError):
        CalibrationConfig(reject_factor=0.5)
