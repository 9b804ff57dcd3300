"""Shared fixtures: the real stereo data set, synthetic cameras and rendered board images.

Synthetic images are rendered with OpenCV (``calibration.synthetic``) through cameras whose
intrinsics, distortion and relative pose are known exactly, so tests compare against truth.
Expensive sets are session-scoped and rendered once.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.boards import BoardSpec, parse_board
from calibration.synthetic import RenderNoise, example_rig, random_board_poses, render_board
from calibration.triangulate import StereoRig
from sim2real.cli.main import main

DATA_DIR = Path(__file__).resolve().parents[1] / "data" / "stereo_chessboard_9x6"
BOARD_9X6 = "chessboard:9x6:0.025"


CliRunner = Callable[..., tuple[int, str, str]]


def _run_cli(*argv: str) -> tuple[int, str, str]:
    """``sim2real calibrate ARGV``: exit code, stdout, stderr."""
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = main(["calibrate", *argv])
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="session")
def run_cli() -> CliRunner:
    """The CLI as a function (pytest's importlib mode cannot import helpers from conftest)."""
    return _run_cli


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The in-repo copy of the 25 real stereo pairs."""
    assert DATA_DIR.is_dir(), f"missing test data {DATA_DIR}"
    return DATA_DIR


@pytest.fixture(scope="session")
def rig() -> StereoRig:
    return example_rig()


@pytest.fixture(scope="session")
def board() -> BoardSpec:
    return parse_board(BOARD_9X6)


@dataclass(frozen=True)
class RenderedStereo:
    """Rendered board pairs saved as left/NN.png and right/NN.png, with the truth."""

    left_dir: Path
    right_dir: Path
    left_T_boards: list[np.ndarray]  # noqa: N815 (frame names)
    rig: StereoRig


def render_stereo_set(
    folder: Path, rig: StereoRig, board: BoardSpec, count: int, seed: int
) -> RenderedStereo:
    rng = np.random.default_rng(seed)
    poses = random_board_poses(
        board, [(rig.left, np.eye(4)), (rig.right, rig.right_T_left)], count, rng
    )
    left_dir, right_dir = folder / "left", folder / "right"
    left_dir.mkdir(parents=True)
    right_dir.mkdir(parents=True)
    noise = RenderNoise(pixel_std=2.0, blur_sigma_px=0.5)
    for i, left_T_board in enumerate(poses):
        img_l = render_board(board, rig.left, left_T_board, rng, noise)
        img_r = render_board(board, rig.right, rig.right_T_left @ left_T_board, rng, noise)
        cv2.imwrite(str(left_dir / f"{i:02d}.png"), img_l)
        cv2.imwrite(str(right_dir / f"{i:02d}.png"), img_r)
    return RenderedStereo(left_dir, right_dir, poses, rig)


@pytest.fixture(scope="session")
def rendered_stereo(
    tmp_path_factory: pytest.TempPathFactory, rig: StereoRig, board: BoardSpec
) -> RenderedStereo:
    """14 rendered chessboard pairs (9×6 inner corners, 25 mm squares)."""
    return render_stereo_set(tmp_path_factory.mktemp("rendered"), rig, board, 14, seed=7)
