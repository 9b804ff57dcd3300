"""``check_stereo``: the triangulated square size exposes a wrong scale, the epipolar error a
wrong rotation."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from calibration.boards import BoardSpec
from calibration.check import check_stereo, neighbour_edges
from calibration.errors import BoardNotFoundError
from calibration.stereo import StereoPair
from calibration.synthetic import project_board, random_board_poses, rotation
from calibration.triangulate import StereoRig


def _pairs(rig: StereoRig, board: BoardSpec, n: int = 6) -> list[StereoPair]:
    rng = np.random.default_rng(5)
    cams = [(rig.left, np.eye(4)), (rig.right, rig.right_T_left)]
    return [
        StereoPair(
            str(i),
            project_board(board, rig.left, P, 0.1, rng),
            project_board(board, rig.right, rig.right_T_left @ P, 0.1, rng),
        )
        for i, P in enumerate(random_board_poses(board, cams, n, rng))
    ]


def test_true_rig_measures_the_board(rig: StereoRig, board: BoardSpec) -> None:
    res = check_stereo(rig, _pairs(rig, board), board)
    assert abs(res.square_size_error_pct) < 0.2
    assert res.epipolar_rms_px < 0.15
    assert len(res.pairs) == 6 and res.skipped == ()


def test_wrong_baseline_shows_as_scale_error(rig: StereoRig, board: BoardSpec) -> None:
    pairs = _pairs(rig, board)
    scaled = dataclasses.replace(rig, T=rig.T * 1.03)
    res = check_stereo(scaled, pairs, board)
    assert res.square_size_error_pct == pytest.approx(3.0, abs=0.3)
    assert res.epipolar_rms_px < 0.15  # same direction of T: epipolar lines unchanged


def test_wrong_rotation_shows_as_epipolar_error(rig: StereoRig, board: BoardSpec) -> None:
    pairs = _pairs(rig, board)
    tilted = dataclasses.replace(rig, R=rotation(0.3, 0, 0) @ rig.R)
    assert check_stereo(tilted, pairs, board).epipolar_rms_px > 1.5


def test_neighbour_edges_and_no_pairs(board: BoardSpec) -> None:
    i, _ = neighbour_edges(board.object_points().astype(np.float64), board.square)
    assert len(i) == 9 * 5 + 8 * 6  # vertical + horizontal neighbours of a 9×6 grid
    with pytest.raises(BoardNotFoundError, match="nothing to check"):
        check_stereo(_dummy_rig(), [StereoPair("x", None, None)], board)


def _dummy_rig() -> StereoRig:
    from calibration.camera import CameraModel

    cam = CameraModel.from_fovy(45.0, 64, 48)
    return StereoRig(cam, cam, np.eye(3), [0.1, 0.0, 0.0])
