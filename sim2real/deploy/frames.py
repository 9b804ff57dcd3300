"""Cameras on their own clock: free-running frame sources the control loop never waits for.

A USB camera delivers frames at its own rate whether or not anybody reads them. Every source here
does the same: capture (or rendering) runs outside the control loop, in a thread or a process,
and publishes the newest pair with its capture time. The loop takes ``latest()`` -- it never
blocks -- and the trackers predict from the capture time to the command time. A source that has
delivered nothing new for ``timeout_s`` raises ``HardwareError``: a dead camera is a fault, a
late frame is not.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from hardware.errors import HardwareError

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class FramePair:
    """Two BGR frames (H, W, 3) uint8 and when they were captured (``time.monotonic()``)."""

    left_bgr: np.ndarray
    right_bgr: np.ndarray
    capture_s: float
    seq: int  # increases by one per published pair


class FrameSource(Protocol):
    """A free-running stereo source; ``start`` before the first ``latest``."""

    timeout_s: float

    def start(self) -> None: ...

    def latest(self) -> FramePair | None:
        """The newest pair, or None before the first one; never blocks."""
        ...

    def close(self) -> None: ...


def wait_first(source: FrameSource, timeout_s: float) -> FramePair:
    """Block until the first pair (start-up only, before torque is on)."""
    deadline = time.monotonic() + timeout_s
    while True:
        pair = source.latest()
        if pair is not None:
            return pair
        if time.monotonic() > deadline:
            raise HardwareError(f"the cameras delivered no frame within {timeout_s:.1f} s")
        time.sleep(0.005)


def check_fresh(source: FrameSource, pair: FramePair, now_s: float) -> None:
    """Raise if the newest pair is older than the source's timeout: the camera stopped."""
    check_fresh_s(source, pair.capture_s, now_s)


def check_fresh_s(source: FrameSource, capture_s: float, now_s: float) -> None:
    """``check_fresh`` on the newest pair's capture time alone (no frame copied for it)."""
    age = now_s - capture_s
    if age > source.timeout_s:
        raise HardwareError(
            f"cameras stopped delivering frames: the newest pair is {age:.2f} s old "
            f"(timeout {source.timeout_s:.2f} s)"
        )


class LatestSlot:
    """The newest value of a producer thread, read without waiting."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._value: FramePair | None = None

    def put(self, value: FramePair) -> None:
        with self._lock:
            self._value = value

    def get(self) -> FramePair | None:
        with self._lock:
            return self._value


class OpenCVStereoCameras:
    """Two ``cv2.VideoCapture`` devices, each read by its own thread at the camera's rate.

    A pair is the newest frame of each camera; its capture time is the older of the two (the
    cameras are not hardware-synchronised: ``skew_s`` of the last pair is reported). A camera
    is a device index or anything ``cv2.VideoCapture`` opens by name (a video file, an image
    sequence such as ``left_%03d.png``, a stream URL): the same capture path, replayable.
    """

    def __init__(
        self, indices: tuple[int | str, int | str], size: tuple[int, int], timeout_s: float = 1.0
    ) -> None:
        import cv2

        self.timeout_s = timeout_s
        self._indices = indices
        self._size = size
        self._caps: list[Any] = []
        self._threads: list[threading.Thread] = []
        self._running = False
        for i in indices:
            cap = cv2.VideoCapture(i)
            if not cap.isOpened():
                cap.release()
                self.close()  # the cameras opened so far are released
                raise HardwareError(
                    f"camera {i!r} could not be opened (is it plugged in and free?)"
                )
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, size[0])
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, size[1])
            cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # the newest frame, not a queue of old ones
            self._caps.append(cap)
        self._frames: list[tuple[np.ndarray, float] | None] = [None, None]
        self._lock = threading.Lock()
        self._seq = 0
        self._error: str | None = None
        self.skew_s = 0.0

    def start(self) -> None:
        self._running = True
        for side in (0, 1):
            t = threading.Thread(target=self._grab, args=(side,), daemon=True, name=f"cam{side}")
            t.start()
            self._threads.append(t)

    def _grab(self, side: int) -> None:
        cap = self._caps[side]
        while self._running:
            ok, frame = cap.read()
            t = time.monotonic()
            if not ok or frame is None:
                time.sleep(0.01)
                continue
            if (frame.shape[1], frame.shape[0]) != self._size:
                self._error = (
                    f"camera {self._indices[side]!r} delivers {frame.shape[1]}x{frame.shape[0]}, "
                    f"but the calibration is for {self._size[0]}x{self._size[1]}: recalibrate or "
                    "set the camera resolution"
                )
                return
            with self._lock:
                self._frames[side] = (frame, t)
                self._seq += 1

    def latest(self) -> FramePair | None:
        if self._error is not None:
            raise HardwareError(self._error)
        with self._lock:
            left, right, seq = self._frames[0], self._frames[1], self._seq
        if left is None or right is None:
            return None
        self.skew_s = abs(left[1] - right[1])
        return FramePair(left[0], right[0], min(left[1], right[1]), seq)

    def close(self) -> None:
        self._running = False
        for t in self._threads:
            t.join(timeout=2.0)
        for cap in self._caps:
            cap.release()
