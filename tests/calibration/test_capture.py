"""Camera protocol: OpenCV VideoCapture (headless, on image sequences) and file replay."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.capture import Camera, OpenCVCamera, ReplayCamera, parse_source, read_pair
from calibration.errors import CaptureError


def _write_frames(folder: Path, count: int) -> None:
    folder.mkdir()
    for i in range(count):
        cv2.imwrite(str(folder / f"{i:04d}.png"), np.full((24, 32, 3), 10 * i, np.uint8))


def test_replay_uses_timestamps_file(tmp_path: Path) -> None:
    _write_frames(tmp_path / "seq", 3)
    (tmp_path / "seq" / "timestamps.csv").write_text(
        "name,timestamp_s\n0000.png,10.0\n0001.png,10.04\n0002.png,10.1\n"
    )
    cam = ReplayCamera(tmp_path / "seq")
    assert isinstance(cam, Camera)
    frames = [cam.read() for _ in range(3)]
    assert [t for _, t in frames] == [10.0, 10.04, 10.1]
    assert [int(f[0, 0, 0]) for f, _ in frames] == [0, 10, 20]
    with pytest.raises(CaptureError, match="ended"):
        cam.read()


def test_replay_fps_and_loop(tmp_path: Path) -> None:
    _write_frames(tmp_path / "seq", 2)
    cam = ReplayCamera(tmp_path / "seq", fps=10.0, loop=True)
    stamps = [cam.read()[1] for _ in range(5)]
    np.testing.assert_allclose(stamps, [0.0, 0.1, 0.2, 0.3, 0.4])  # time keeps increasing


def test_replay_errors(tmp_path: Path) -> None:
    _write_frames(tmp_path / "seq", 2)
    (tmp_path / "seq" / "timestamps.csv").write_text("name,timestamp_s\n0000.png,1.0\n")
    with pytest.raises(CaptureError, match="no timestamp for 0001.png"):
        ReplayCamera(tmp_path / "seq")
    with pytest.raises(CaptureError, match="fps must be positive"):
        ReplayCamera(tmp_path / "seq", fps=0)


def test_opencv_camera_on_an_image_sequence(tmp_path: Path) -> None:
    _write_frames(tmp_path / "a", 3)
    _write_frames(tmp_path / "b", 3)
    with (
        OpenCVCamera(str(tmp_path / "a" / "%04d.png")) as cam_a,
        OpenCVCamera(str(tmp_path / "b" / "%04d.png")) as cam_b,
    ):
        assert isinstance(cam_a, Camera)
        pair = read_pair([cam_a, cam_b])
        assert [f.shape for f, _ in pair] == [(24, 32, 3), (24, 32, 3)]
        assert abs(pair[0][1] - pair[1][1]) < 0.05  # grabbed back to back
        frame, t1 = cam_a.read()
        assert int(frame[0, 0, 0]) == 10 and t1 >= pair[0][1]
        cam_a.read()
        with pytest.raises(CaptureError, match="no frame"):
            cam_a.read()


def test_opencv_camera_missing_source(tmp_path: Path) -> None:
    with pytest.raises(CaptureError, match="cannot open video source"):
        OpenCVCamera(str(tmp_path / "missing_%04d.png"))
    with pytest.raises(CaptureError, match="cannot open camera index 57"):
        OpenCVCamera(57)


def test_parse_source() -> None:
    assert parse_source("0") == 0 and parse_source(" 12 ") == 12
    assert parse_source("rtsp://cam/stream") == "rtsp://cam/stream"
