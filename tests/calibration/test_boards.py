"""Board specs, detection on rendered images, canonical corner order and error messages."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.boards import BOARD_KINDS, CharucoSpec, ChessboardSpec, parse_board
from calibration.camera import CameraModel
from calibration.errors import BoardSpecError, UnknownNameError
from calibration.synthetic import pose, render_board, rotation

CAM = CameraModel.from_fovy(50.0, 640, 480)


def _truth_px(board: ChessboardSpec | CharucoSpec, cam_T_board: np.ndarray, ids: np.ndarray):
    obj = board.object_points()[ids].astype(np.float64)
    return CAM.project(obj @ cam_T_board[:3, :3].T + cam_T_board[:3, 3])


def _front_pose(board: ChessboardSpec | CharucoSpec, roll_deg: float = 0.0) -> np.ndarray:
    """A board centred 0.45 m in front of the camera, slightly tilted, rolled by ``roll_deg``."""
    R = rotation(12.0, -8.0, roll_deg)
    centre = board.object_points().astype(np.float64).mean(axis=0)
    return pose(R, np.array([0.0, 0.0, 0.45]) - R @ centre)


def test_parse_chessboard_and_charuco() -> None:
    chess = parse_board("chessboard:9x6:0.025")
    assert isinstance(chess, ChessboardSpec)
    assert (chess.cols, chess.rows, chess.square) == (9, 6, 0.025)
    assert str(chess) == "chessboard:9x6:0.025"
    charuco = parse_board("charuco:7x5:0.04:0.03:4X4_50:legacy")
    assert isinstance(charuco, CharucoSpec)
    assert charuco.dictionary == "DICT_4X4_50"
    assert charuco.legacy is True
    assert charuco.corner_count == 24
    assert parse_board("charuco:7x5:0.04:0.03:DICT_5X5_100").legacy is None  # auto


@pytest.mark.parametrize(
    ("spec", "fragment"),
    [
        ("chessbored:9x6:0.025", "valid: charuco, chessboard"),
        ("chessboard:9x6", "expected chessboard:COLSxROWS:SQUARE"),
        ("chessboard:9by6:0.025", "must look like 9x6"),
        ("chessboard:9x6:-1", "positive"),
        ("chessboard:9x6:abc", "'abc' is not a number"),
        ("chessboard:7x7:0.02", "is square"),
        ("charuco:7x5:0.04:0.05:DICT_4X4_50", "must be smaller than the square"),
        ("charuco:7x5:0.04:0.03:DICT_9X9_1", "unknown ArUco dictionary 'DICT_9X9_1'; valid:"),
        ("charuco:7x5:0.04:0.03:DICT_4X4_50:old", "unknown ChArUco layout 'old'"),
        ("charuco:12x11:0.04:0.03:DICT_4X4_50", "has 50 markers"),
    ],
)
def test_bad_board_strings_name_the_problem(spec: str, fragment: str) -> None:
    with pytest.raises((BoardSpecError, UnknownNameError)) as info:
        parse_board(spec)
    assert fragment in str(info.value)
    assert "\n" not in str(info.value)


def test_unknown_dictionary_lists_choices() -> None:
    with pytest.raises(UnknownNameError) as info:
        parse_board("charuco:5x7:0.04:0.03:DICT_7X7_9999")
    assert "DICT_4X4_50" in str(info.value) and "DICT_6X6_250" in str(info.value)
    assert set(BOARD_KINDS) == {"chessboard", "charuco"}


@pytest.mark.parametrize("roll_deg", [0.0, 180.0, 90.0, -100.0])
def test_chessboard_detection_is_accurate_and_canonical(roll_deg: float) -> None:
    """Whatever way up the board is, corner k of the detection is corner k of the board."""
    board = parse_board("chessboard:9x6:0.025")
    cam_T_board = _front_pose(board, roll_deg)
    img = render_board(board, CAM, cam_T_board, np.random.default_rng(1))
    det = board.detect(img)
    assert det is not None and len(det) == 54
    err = np.linalg.norm(det.image_points - _truth_px(board, cam_T_board, det.ids), axis=1)
    assert err.max() < 0.15, err.max()


def test_point_symmetric_board_is_flagged() -> None:
    assert parse_board("chessboard:8x6:0.02").point_symmetric
    assert not parse_board("chessboard:9x6:0.02").point_symmetric


def test_charuco_detection_accurate() -> None:
    board = parse_board("charuco:7x5:0.03:0.022:DICT_4X4_50")
    cam_T_board = _front_pose(board, 20.0)
    img = render_board(board, CAM, cam_T_board, np.random.default_rng(2))
    det = board.detect(img)
    assert det is not None and len(det) == board.corner_count
    assert det.layout == "new"
    err = np.linalg.norm(det.image_points - _truth_px(board, cam_T_board, det.ids), axis=1)
    assert err.max() < 0.25, err.max()


def test_legacy_charuco_found_by_auto_and_not_by_new() -> None:
    """Boards printed before OpenCV 4.6 with an even row count need setLegacyPattern."""
    legacy = parse_board("charuco:5x6:0.03:0.022:DICT_4X4_50:legacy")
    cam_T_board = _front_pose(legacy)
    img = render_board(legacy, CAM, cam_T_board, np.random.default_rng(3))
    auto = parse_board("charuco:5x6:0.03:0.022:DICT_4X4_50")
    det = auto.detect(img)
    assert det is not None and det.layout == "legacy" and len(det) == legacy.corner_count
    err = np.linalg.norm(det.image_points - _truth_px(legacy, cam_T_board, det.ids), axis=1)
    assert err.max() < 0.25
    assert parse_board("charuco:5x6:0.03:0.022:DICT_4X4_50:new").detect(img) is None
    message = parse_board("charuco:5x6:0.03:0.022:DICT_4X4_50:new").diagnose_missing([img])
    assert "markers were found but no ChArUco corners" in message


def test_squares_instead_of_inner_corners_is_explained() -> None:
    real = parse_board("chessboard:9x6:0.025")
    img = render_board(real, CAM, _front_pose(real), np.random.default_rng(4))
    mistaken = parse_board("chessboard:10x7:0.025")
    assert mistaken.detect(img) is None
    hint = mistaken.diagnose_missing([img])
    assert "counts inner corners, not squares" in hint
    assert "chessboard:9x6:0.025" in hint


def test_no_board_at_all() -> None:
    blank = np.full((480, 640), 128, np.uint8)
    board = parse_board("chessboard:9x6:0.025")
    assert board.detect(blank) is None
    assert "inner corners" in board.diagnose_missing([blank])


def test_texture_maps_board_units_to_pixels() -> None:
    """The first inner corner sits at the meeting point of four squares in the texture."""
    board = parse_board("chessboard:9x6:0.025")
    tex, tex_from_board = board.texture(40)
    u, v, _ = tex_from_board @ np.array([0.0, 0.0, 1.0])
    # pixel centres at integers: the corner is between pixels 79 and 80
    assert (u, v) == (79.5, 79.5)
    assert tex[75, 75] == 0 and tex[75, 84] == 255 and tex[84, 84] == 0


def test_canonical_order_undoes_turns_and_mirrors() -> None:
    """The colour/handedness rule restores the board order from any of the four grid orders a
    corner finder may return for a non-symmetric board."""
    from calibration.boards import _canonical_grid

    board = parse_board("chessboard:9x6:0.025")
    cam_T_board = _front_pose(board, 35.0)
    img = render_board(board, CAM, cam_T_board, np.random.default_rng(5))
    truth = _truth_px(board, cam_T_board, np.arange(54)).reshape(6, 9, 2).astype(np.float32)
    for scrambled in (truth, truth[::-1, ::-1], truth[:, ::-1], truth[::-1, :]):
        restored = _canonical_grid(scrambled, img, colour_check=True)
        np.testing.assert_allclose(restored, truth)
    # A point-symmetric board keeps its order apart from the mirror fix: a 180° turn is invisible.
    turned = _canonical_grid(truth[::-1, ::-1], img, colour_check=False)
    np.testing.assert_allclose(turned, truth[::-1, ::-1])
