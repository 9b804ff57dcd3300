"""Live capture for calibration: keep the frames that add something, say what is missing.

Frames come from any :class:`~calibration.capture.Camera` (``cv2.VideoCapture``, headless). A
frame (a frame pair for stereo) is accepted when every camera sees the board and the board has
moved by ``min_change_px`` on average since every accepted view, so twenty near-identical frames
of a board held still count once. Accepted frames are saved as PNG (atomically) under
``out_dir/frames/<camera>/NNNN.png`` (same name in both cameras, so stereo pairs by name), and a
coverage line is reported after each acceptance so the user knows where to move the board next.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calibration.boards import BoardSpec, Detection
from calibration.capture import Camera, read_pair
from calibration.errors import BoardNotFoundError, CaptureError, ConfigError
from calibration.markers import to_gray
from s2r_common.atomic import atomic_write_bytes


@dataclass(frozen=True)
class LiveConfig:
    target_views: int = 20
    max_frames: int = 3000
    min_change_px: float = 25.0
    grid: tuple[int, int] = (4, 3)  # coverage cells across, down (coarse: for people)

    def __post_init__(self) -> None:
        if self.target_views < 3 or self.max_frames < 1 or self.min_change_px < 0:
            raise ConfigError(
                f"live capture needs target_views ≥ 3, max_frames ≥ 1, min_change_px ≥ 0; got "
                f"{self.target_views}, {self.max_frames}, {self.min_change_px}"
            )


def _change_px(a: Detection, b: Detection) -> float:
    common, ia, ib = np.intersect1d(a.ids, b.ids, return_indices=True)
    if len(common) == 0:
        return float("inf")
    return float(np.linalg.norm(a.image_points[ia] - b.image_points[ib], axis=1).mean())


def coverage_text(cells: np.ndarray) -> str:
    """A one-line map: ``#`` covered cell, ``.`` empty; rows separated by ``|``."""
    return "|".join("".join("#" if v else "." for v in row) for row in cells)


def capture_views(
    cameras: Sequence[Camera],
    names: Sequence[str],
    board: BoardSpec,
    out_dir: Path,
    config: LiveConfig | None = None,
    log: Callable[[str], None] = print,
) -> list[Path]:
    """Capture until ``target_views`` are accepted or the streams end; returns the folders."""
    config = config or LiveConfig()
    folders = [out_dir / "frames" / name for name in names]
    accepted: list[list[Detection]] = [[] for _ in cameras]
    cells = [np.zeros((config.grid[1], config.grid[0]), bool) for _ in cameras]
    frames_read = 0
    while frames_read < config.max_frames and len(accepted[0]) < config.target_views:
        try:
            frames = read_pair(cameras)
        except CaptureError:
            if frames_read == 0:
                raise
            break  # end of a stream: calibrate with what we have
        frames_read += 1
        grays = [to_gray(f) for f, _ in frames]
        dets = [board.detect(g) for g in grays]
        if any(d is None for d in dets):
            continue
        found = [d for d in dets if d is not None]
        if accepted[0] and not all(
            min(_change_px(d, prev) for prev in acc) >= config.min_change_px
            for d, acc in zip(found, accepted, strict=True)
        ):
            continue
        index = len(accepted[0])
        for k, (gray, det) in enumerate(zip(grays, found, strict=True)):
            accepted[k].append(det)
            ok, png = cv2.imencode(".png", gray)
            if not ok:
                raise CaptureError("could not encode a captured frame as PNG")
            atomic_write_bytes(folders[k] / f"{index:04d}.png", png.tobytes())
            height, width = gray.shape
            gx, gy = config.grid
            pts = det.image_points
            cx = np.clip((pts[:, 0] / width * gx).astype(int), 0, gx - 1)
            cy = np.clip((pts[:, 1] / height * gy).astype(int), 0, gy - 1)
            cells[k][cy, cx] = True
        status = "  ".join(
            f"{name} {100 * c.mean():.0f}% [{coverage_text(c)}]"
            for name, c in zip(names, cells, strict=True)
        )
        log(f"accepted {index + 1}/{config.target_views} (frame {frames_read})  coverage {status}")
        missing = [coverage_text(c) for c in cells if not c.all()]
        if missing:
            log("  move the board towards the '.' cells")
    if len(accepted[0]) < 3:
        raise BoardNotFoundError(
            f"live capture accepted only {len(accepted[0])} view(s) in {frames_read} frames; "
            "show the whole board to every camera and move it between views"
        )
    return folders
