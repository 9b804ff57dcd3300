"""Package hygiene: import weight, allowed dependencies, the report (the atomic writer is
``s2r_common.atomic``, tested in ``tests/s2r_common``)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from calibration.intrinsics import View, calibrate_camera
from calibration.report import markdown_report, render_png
from calibration.synthetic import project_board, random_board_poses
from calibration.triangulate import StereoRig

REPO = Path(__file__).resolve().parents[2]
MODULES = [p.stem for p in (REPO / "calibration").glob("*.py") if p.stem != "__init__"]


def _python(code: str) -> str:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    result = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env=env,
        check=True,
        timeout=120,
    )
    return result.stdout.strip()


def test_errors_module_is_import_light() -> None:
    """The CLI imports calibration.errors for every command: it must not pull in cv2/numpy."""
    out = _python(
        "import sys, calibration.errors; print(sorted(m for m in ('cv2', 'numpy', 'filterpy') "
        "if m in sys.modules))"
    )
    assert out == "[]"


def test_only_numpy_opencv_filterpy_are_imported() -> None:
    code = (
        "import sys\n"
        + "".join(f"import calibration.{m}\n" for m in MODULES)
        + "bad = ('mujoco', 'torch', 'yaml', 'matplotlib', 'hardware', 'sim2real', 'serial')\n"
        + "print(sorted(b for b in bad if b in sys.modules))"
    )
    assert _python(code) == "[]"


def test_report_markdown_and_png(rig: StereoRig, board) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(0)
    poses = random_board_poses(board, [(rig.left, np.eye(4))], 8, rng)
    views = [
        View(f"img{i}.png", d)
        for i, P in enumerate(poses)
        if (d := project_board(board, rig.left, P, 0.2, rng)) is not None
    ]
    res = calibrate_camera(views, (640, 480), name="left", failed=["dark.png"])
    md = markdown_report(res, "chessboard:9x6:0.025")
    for section in (
        "## Intrinsics",
        "## Odd/even cross-validation",
        "## Coverage",
        "## Warnings",
        "| dark.png | — | no | no board |",
        "![residuals",
    ):
        assert section in md
    png = render_png(res)
    assert png is not None
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None and img.shape[1] > 1000
