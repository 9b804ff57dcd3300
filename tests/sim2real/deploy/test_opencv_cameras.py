"""The OpenCV camera path (``OpenCVStereoCameras``, what ``deploy --backend serial`` reads) on
real ``cv2.VideoCapture`` captures of video files written by ``cv2.VideoWriter``: frames arrive
through the capture threads, a wrong resolution and a missing camera are one-line errors, and a
camera that stops delivering (the file ends) trips the freshness check.

Every wait is for an event, bounded far above what a loaded machine needs."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
from timescale import scaled  # type: ignore[import-not-found]

from hardware.errors import HardwareError
from sim2real.deploy.frames import OpenCVStereoCameras, check_fresh, wait_first

W, H, N = 64, 48, 30
BOUND_S = scaled(30.0)


def _video(path: Path, shade: int) -> Path:
    """N frames of a grey level ``shade`` with a white square moving across (MJPG)."""
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (W, H))
    assert out.isOpened(), "OpenCV cannot write MJPG here"
    try:
        for i in range(N):
            frame = np.full((H, W, 3), shade, np.uint8)
            frame[10:20, i : i + 10] = 255
            out.write(frame)
    finally:
        out.release()
    return path


@pytest.fixture
def videos(tmp_path: Path) -> tuple[str, str]:
    return str(_video(tmp_path / "left.avi", 40)), str(_video(tmp_path / "right.avi", 160))


@pytest.fixture
def cameras(videos: tuple[str, str]) -> Iterator[OpenCVStereoCameras]:
    cams = OpenCVStereoCameras(videos, (W, H), timeout_s=scaled(1.0))
    try:
        yield cams
    finally:
        cams.close()  # the capture threads joined, the captures released


def test_file_backed_captures_deliver_pairs_through_the_capture_threads(
    cameras: OpenCVStereoCameras,
) -> None:
    cameras.start()
    first = wait_first(cameras, BOUND_S)
    assert first.left_bgr.shape == first.right_bgr.shape == (H, W, 3)
    # each side is its own file: the left dark, the right light (MJPG is lossy: a margin)
    assert abs(float(np.median(first.left_bgr)) - 40) < 8
    assert abs(float(np.median(first.right_bgr)) - 160) < 8
    deadline = time.monotonic() + BOUND_S
    while (pair := cameras.latest()) is not None and pair.seq < 4:
        assert time.monotonic() < deadline, "the capture threads stopped delivering"
        time.sleep(0.005)
    assert pair is not None and pair.seq >= 4 and pair.capture_s >= first.capture_s


def test_a_file_that_ends_is_a_camera_that_stopped_delivering(
    cameras: OpenCVStereoCameras,
) -> None:
    cameras.start()
    wait_first(cameras, BOUND_S)
    deadline = time.monotonic() + BOUND_S + cameras.timeout_s
    with pytest.raises(HardwareError, match=r"cameras stopped delivering frames: the newest "):
        while time.monotonic() < deadline:  # the files hold 30 frames: they end
            pair = cameras.latest()
            assert pair is not None
            check_fresh(cameras, pair, time.monotonic())
            time.sleep(0.01)


def test_a_capture_at_another_resolution_is_refused_in_one_line(
    videos: tuple[str, str],
) -> None:
    cams = OpenCVStereoCameras(videos, (2 * W, 2 * H))
    try:
        cams.start()
        deadline = time.monotonic() + BOUND_S
        with pytest.raises(HardwareError, match=rf"delivers {W}x{H}, but the calibration is for"):
            while time.monotonic() < deadline:
                cams.latest()
                time.sleep(0.005)
    finally:
        cams.close()


def test_a_camera_that_cannot_be_opened_is_named(tmp_path: Path) -> None:
    missing = str(tmp_path / "missing.avi")
    with pytest.raises(HardwareError, match="missing.avi' could not be opened") as err:
        OpenCVStereoCameras((missing, missing), (W, H))
    assert "\n" not in str(err.value)
