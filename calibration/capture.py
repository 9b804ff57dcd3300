"""Cameras: a ``Camera`` protocol with an OpenCV and a file-replay implementation.

Every camera returns ``(frame, timestamp_s)``: the timestamp is taken when the frame is grabbed
(``time.monotonic``) or read from a replay's ``timestamps.csv``, so a Kalman filter downstream
gets the real time between frames, not the loop's. The deploy code adds a MuJoCo-rendered camera
with the same protocol.
"""

from __future__ import annotations

import csv
import io
import os
import time
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from calibration.dataset import list_images
from calibration.errors import CaptureError


@runtime_checkable
class Camera(Protocol):
    """Anything that yields frames with their capture time."""

    def read(self) -> tuple[np.ndarray, float]:
        """The next frame (H,W,3 BGR or H,W gray uint8) and its timestamp in seconds."""
        ...

    def close(self) -> None: ...


def parse_source(text: str) -> int | str:
    """``"0"`` → device index 0; anything else (a path, a URL, an image pattern) stays a string."""
    stripped = text.strip()
    return int(stripped) if stripped.isdigit() else stripped


class OpenCVCamera:
    """``cv2.VideoCapture`` on a device index, a video file, a URL or an image pattern
    (``frames/left_%03d.png``). Headless: nothing is displayed.

    ``grab`` and ``retrieve`` are split so two cameras can be grabbed back to back and decoded
    afterwards, which keeps a stereo pair close in time.
    """

    def __init__(
        self,
        source: int | str,
        width: int | None = None,
        height: int | None = None,
        fps: float | None = None,
    ) -> None:
        self.source = source
        # OpenCV logs its own lines when a device is missing; the CaptureError says it once.
        level = cv2.getLogLevel()
        cv2.setLogLevel(0)  # 0 = LOG_LEVEL_SILENT
        try:
            self._cap = cv2.VideoCapture(source)
        finally:
            cv2.setLogLevel(level)
        if not self._cap.isOpened():
            self._cap.release()
            kind = "camera index" if isinstance(source, int) else "video source"
            raise CaptureError(f"cannot open {kind} {source!r}")
        for prop, value in ((cv2.CAP_PROP_FRAME_WIDTH, width), (cv2.CAP_PROP_FRAME_HEIGHT, height),
                            (cv2.CAP_PROP_FPS, fps)):  # fmt: skip
            if value is not None:
                self._cap.set(prop, float(value))
        self._t_grab = 0.0

    def grab(self) -> float:
        """Latch the next frame; returns its timestamp."""
        if not self._cap.grab():
            raise CaptureError(f"camera {self.source!r} delivered no frame (end of stream?)")
        self._t_grab = time.monotonic()
        return self._t_grab

    def retrieve(self) -> tuple[np.ndarray, float]:
        ok, frame = self._cap.retrieve()
        if not ok or frame is None:
            raise CaptureError(f"camera {self.source!r}: could not decode the grabbed frame")
        return np.asarray(frame), self._t_grab

    def read(self) -> tuple[np.ndarray, float]:
        self.grab()
        return self.retrieve()

    def close(self) -> None:
        self._cap.release()

    def __enter__(self) -> OpenCVCamera:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class ReplayCamera:
    """Frames from a folder of images, in name order, for offline runs and tests.

    Timestamps come from ``timestamps.csv`` (``name,timestamp_s``) in the folder when present,
    otherwise from ``fps``. ``loop`` restarts at the end instead of raising ``CaptureError``.
    """

    def __init__(
        self, folder: str | os.PathLike[str], fps: float = 20.0, loop: bool = False
    ) -> None:
        if not fps > 0:
            raise CaptureError(f"fps must be positive, got {fps}")
        self.paths = list_images(folder)
        self.loop = loop
        self._index = 0
        stamps_file = Path(folder) / "timestamps.csv"
        self._stamps = (
            self._read_stamps(stamps_file)
            if stamps_file.is_file()
            else {p.name: i / fps for i, p in enumerate(self.paths)}
        )
        missing = [p.name for p in self.paths if p.name not in self._stamps]
        if missing:
            raise CaptureError(f"{stamps_file}: no timestamp for {', '.join(missing[:5])}")
        # One lap lasts from the first frame to one mean frame interval after the last.
        first, last = self._stamps[self.paths[0].name], self._stamps[self.paths[-1].name]
        mean_dt = (last - first) / (len(self.paths) - 1) if len(self.paths) > 1 else 1.0 / fps
        self._lap_s = last - first + mean_dt
        self._laps = 0

    @staticmethod
    def _read_stamps(path: Path) -> dict[str, float]:
        stamps: dict[str, float] = {}
        for row in csv.DictReader(io.StringIO(path.read_text(encoding="utf-8"))):
            try:
                stamps[row["name"]] = float(row["timestamp_s"])
            except (KeyError, TypeError, ValueError):
                raise CaptureError(
                    f"{path}: expected columns name,timestamp_s; got {row}"
                ) from None
        return stamps

    def __len__(self) -> int:
        return len(self.paths)

    def read(self) -> tuple[np.ndarray, float]:
        if self._index >= len(self.paths):
            if not self.loop:
                raise CaptureError(f"replay of {len(self.paths)} frames has ended")
            self._index = 0
            self._laps += 1
        path = self.paths[self._index]
        self._index += 1
        frame = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if frame is None:
            raise CaptureError(f"cannot decode replay frame {path}")
        return np.asarray(frame), self._stamps[path.name] + self._laps * self._lap_s

    def close(self) -> None:
        self._index = len(self.paths)


def read_pair(cameras: Sequence[Camera]) -> list[tuple[np.ndarray, float]]:
    """Read one frame from each camera, grabbing all before decoding any when possible."""
    if all(isinstance(c, OpenCVCamera) for c in cameras):
        opencv = [c for c in cameras if isinstance(c, OpenCVCamera)]
        for cam in opencv:
            cam.grab()
        return [cam.retrieve() for cam in opencv]
    return [cam.read() for cam in cameras]
