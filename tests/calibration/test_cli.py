"""``sim2real calibrate``: bad input gives one line naming the cause, exit 2, and no files;
``--live`` captures headless from cv2.VideoCapture sources."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

BOARD = "chessboard:9x6:0.025"


def _copy(src: Path, dst: Path, names: list[str]) -> Path:
    dst.mkdir(parents=True, exist_ok=True)
    for name in names:
        shutil.copy(src / name, dst / name)
    return dst


def _names(folder: Path, count: int) -> list[str]:
    return sorted(p.name for p in folder.iterdir())[:count]


def _assert_one_line_error(code: int, stdout: str, stderr: str, *fragments: str) -> None:
    assert code == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith("sim2real calibrate: error: ")
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    assert stdout == ""


def test_empty_folder(tmp_path: Path, run_cli: Any) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("not an image")
    out = tmp_path / "out"
    _assert_one_line_error(
        *run_cli("intrinsics", "--images", str(empty), "--board", BOARD, "--out", str(out)),
        "no images",
        str(empty),
    )
    assert not out.exists()


def test_missing_folder(tmp_path: Path, run_cli: Any) -> None:
    _assert_one_line_error(
        *run_cli(
            "intrinsics",
            "--images",
            str(tmp_path / "nope"),
            "--board",
            BOARD,
            "--out",
            str(tmp_path / "out"),
        ),
        "image folder not found",
    )


def test_no_board_in_any_image(tmp_path: Path, run_cli: Any) -> None:
    folder = tmp_path / "blank"
    folder.mkdir()
    for i in range(4):
        cv2.imwrite(str(folder / f"{i}.png"), np.full((480, 640), 90 + 10 * i, np.uint8))
    out = tmp_path / "out"
    _assert_one_line_error(
        *run_cli("intrinsics", "--images", str(folder), "--board", BOARD, "--out", str(out)),
        "no chessboard:9x6:0.025 found in any of 4 images",
    )
    assert not out.exists()


def test_wrong_board_size_says_inner_corners(
    tmp_path: Path, rendered_stereo: Any, run_cli: Any
) -> None:
    folder = _copy(rendered_stereo.left_dir, tmp_path / "imgs", _names(rendered_stereo.left_dir, 3))
    _assert_one_line_error(
        *run_cli(
            "intrinsics",
            "--images",
            str(folder),
            "--board",
            "chessboard:10x7:0.025",
            "--out",
            str(tmp_path / "out"),
        ),
        "counts inner corners, not squares",
        "chessboard:9x6:0.025",
    )


def test_mismatched_pairs(tmp_path: Path, rendered_stereo: Any, run_cli: Any) -> None:
    names = _names(rendered_stereo.left_dir, 6)
    left = _copy(rendered_stereo.left_dir, tmp_path / "l", names)
    right = _copy(rendered_stereo.right_dir, tmp_path / "r", names[:5])
    _assert_one_line_error(
        *run_cli(
            "stereo",
            "--left",
            str(left),
            "--right",
            str(right),
            "--board",
            BOARD,
            "--out",
            str(tmp_path / "out"),
        ),
        "mismatched pairs: 6 left and 5 right images",
        f"without a right image: {names[5]}",
    )


@pytest.mark.parametrize(
    ("name", "content", "fragment"),
    [
        ("broken.png", b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4 + b"IEND\xaeB`\x82", "corrupt"),
        ("cut.jpg", None, "truncated"),
        ("empty.png", b"", "is empty"),
    ],
)
def test_corrupt_image(
    tmp_path: Path,
    rendered_stereo: Any,
    run_cli: Any,
    name: str,
    content: bytes | None,
    fragment: str,
) -> None:
    folder = _copy(rendered_stereo.left_dir, tmp_path / "imgs", _names(rendered_stereo.left_dir, 5))
    if content is None:  # a real JPEG cut in half
        ok, jpg = cv2.imencode(".jpg", cv2.imread(str(folder / "00.png")))
        assert ok
        content = jpg.tobytes()[: len(jpg) // 2]
    (folder / name).write_bytes(content)
    _assert_one_line_error(
        *run_cli(
            "intrinsics", "--images", str(folder), "--board", BOARD, "--out", str(tmp_path / "out")
        ),
        fragment,
        name,
    )


def test_unknown_dictionary(tmp_path: Path, run_cli: Any) -> None:
    _assert_one_line_error(
        *run_cli(
            "intrinsics",
            "--images",
            str(tmp_path),
            "--board",
            "charuco:7x5:0.04:0.03:DICT_4X4_51",
            "--out",
            str(tmp_path / "out"),
        ),
        "unknown ArUco dictionary 'DICT_4X4_51'",
        "DICT_4X4_50",
    )


def test_failed_run_keeps_previous_calibration(
    tmp_path: Path, rendered_stereo: Any, run_cli: Any
) -> None:
    """A run that fails never replaces or truncates the files of an earlier good one."""
    out = tmp_path / "out"
    code, _, stderr = run_cli(
        "intrinsics",
        "--images",
        str(rendered_stereo.left_dir),
        "--board",
        BOARD,
        "--out",
        str(out),
    )
    assert code == 0, stderr
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    blank = tmp_path / "blank"
    blank.mkdir()
    cv2.imwrite(str(blank / "a.png"), np.zeros((480, 640), np.uint8))
    code, _, _ = run_cli("intrinsics", "--images", str(blank), "--board", BOARD, "--out", str(out))
    assert code == 2
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # no temp files either


def test_live_capture_from_videocapture(tmp_path: Path, rendered_stereo: Any, run_cli: Any) -> None:
    """cv2.VideoCapture reads image sequences headless; repeated frames of a still board and a
    frame without the board are not accepted, and coverage feedback is printed."""
    names = _names(rendered_stereo.left_dir, 8)
    sequence = [names[0], names[0], names[1], names[1], names[2], "blank", *names[3:]]
    for side, src in (("l", rendered_stereo.left_dir), ("r", rendered_stereo.right_dir)):
        folder = tmp_path / side
        folder.mkdir()
        for i, name in enumerate(sequence):
            target = folder / f"{i:04d}.png"
            if name == "blank":
                cv2.imwrite(str(target), np.full((480, 640), 128, np.uint8))
            else:
                shutil.copy(src / name, target)
    out = tmp_path / "out"
    code, stdout, stderr = run_cli(
        "stereo",
        "--live",
        "--cameras",
        f"{tmp_path / 'l' / '%04d.png'},{tmp_path / 'r' / '%04d.png'}",
        "--views",
        "6",
        "--board",
        BOARD,
        "--out",
        str(out),
        "--json",
    )
    assert code == 0, stderr
    saved = sorted(p.name for p in (out / "frames" / "left").iterdir())
    assert saved == [f"{i:04d}.png" for i in range(6)]
    assert sorted(p.name for p in (out / "frames" / "right").iterdir()) == saved
    assert "accepted 1/6 (frame 1)" in stderr and "accepted 2/6 (frame 3)" in stderr
    assert "coverage left" in stderr
    summary = json.loads(stdout)
    assert summary["views_used"] == 6
    assert summary["baseline"] == pytest.approx(rendered_stereo.rig.baseline, rel=0.01)


def test_live_without_cameras(tmp_path: Path, run_cli: Any) -> None:
    _assert_one_line_error(
        *run_cli("intrinsics", "--live", "--board", BOARD, "--out", str(tmp_path)),
        "--live needs --cameras",
    )
    _assert_one_line_error(
        *run_cli(
            "intrinsics", "--live", "--cameras", "0,1", "--board", BOARD, "--out", str(tmp_path)
        ),
        "expected 1 source(s)",
    )
    missing = tmp_path / "none_%04d.png"
    _assert_one_line_error(
        *run_cli(
            "intrinsics",
            "--live",
            "--cameras",
            str(missing),
            "--board",
            BOARD,
            "--out",
            str(tmp_path),
        ),
        "cannot open video source",
    )


def test_no_absolute_paths_in_outputs_besides_the_summary(
    tmp_path: Path, rendered_stereo: Any, run_cli: Any
) -> None:
    out = tmp_path / "o"
    code, _, _ = run_cli(
        "intrinsics",
        "--images",
        str(rendered_stereo.left_dir),
        "--board",
        BOARD,
        "--out",
        str(out),
        "--model",
        "k1k2",
    )
    assert code == 0
    for name in ("camera.yaml", "camera_info.yaml"):
        assert os.fspath(tmp_path) not in (out / name).read_text()
    fs = cv2.FileStorage(str(out / "camera.yaml"), cv2.FILE_STORAGE_READ)
    assert fs.getNode("distortion_coefficients").mat().ravel()[4] == 0.0  # k3 fixed
    fs.release()
