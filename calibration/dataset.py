"""Image folders: listing, pairing left/right images by name, reading and detecting boards.

Everything a user can get wrong about the input (an empty or missing folder, a corrupt or
truncated image, images of different sizes, left and right sets that do not pair up) is refused
here with a one-line :class:`~calibration.errors.ImageError` that names the file or folder.
"""

from __future__ import annotations

import glob
import os
import re
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calibration.boards import BoardSpec, Detection
from calibration.errors import BoardNotFoundError, ImageError

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")
_SIDE_RE = re.compile(r"left|right", re.IGNORECASE)


def list_images(source: str | os.PathLike[str]) -> list[Path]:
    """Images in a folder (sorted by name) or matching a glob pattern such as ``dir/left*.jpg``."""
    text = os.fspath(source)
    if any(ch in text for ch in "*?["):
        paths = [Path(p) for p in sorted(glob.glob(text))]
        where = f"pattern {text!r}"
    else:
        folder = Path(text)
        if not folder.is_dir():
            raise ImageError(f"image folder not found: {folder}")
        paths = sorted(p for p in folder.iterdir())
        where = f"folder {folder}"
    images = [p for p in paths if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS]
    if not images:
        raise ImageError(f"no images ({', '.join(IMAGE_EXTENSIONS)}) in {where}")
    return images


def pair_key(path: Path) -> str:
    """The part of the name both cameras share: ``left01.jpg`` and ``right01.jpg`` → ``01``."""
    return _SIDE_RE.sub("", path.stem, count=1).strip("_-. ").lower() or path.stem.lower()


def pair_images(left: Sequence[Path], right: Sequence[Path]) -> list[tuple[str, Path, Path]]:
    """Match left and right images by name; refuse sets that do not pair up one to one.

    When both lists come from the same folder, only names with ``left``/``right`` in them count.
    """
    if {p.parent for p in left} == {p.parent for p in right}:
        left = [p for p in left if "left" in p.stem.lower()]
        right = [p for p in right if "right" in p.stem.lower()]
        if not left or not right:
            raise ImageError(
                "--left and --right name the same folder but its images are not named "
                "left*/right*; give two folders or glob patterns"
            )
    lkeys = {pair_key(p): p for p in left}
    rkeys = {pair_key(p): p for p in right}
    if len(lkeys) != len(left) or len(rkeys) != len(right):
        raise ImageError("two images in one folder map to the same pair name")
    if lkeys.keys() != rkeys.keys():
        only_l = sorted(lkeys.keys() - rkeys.keys())
        only_r = sorted(rkeys.keys() - lkeys.keys())
        detail = "; ".join(
            part
            for part in (
                f"without a right image: {', '.join(lkeys[k].name for k in only_l[:5])}"
                if only_l
                else "",
                f"without a left image: {', '.join(rkeys[k].name for k in only_r[:5])}"
                if only_r
                else "",
            )
            if part
        )
        raise ImageError(
            f"mismatched pairs: {len(left)} left and {len(right)} right images; {detail}"
        )
    return [(k, lkeys[k], rkeys[k]) for k in sorted(lkeys)]


def _truncated(data: bytes, suffix: str) -> bool:
    """JPEG and PNG decoders return a half-grey image for a truncated file; their end markers
    (JPEG EOI ``FFD9``, PNG ``IEND``) tell a complete file from a cut one."""
    if suffix in (".jpg", ".jpeg"):
        return b"\xff\xd9" not in data[-64:]
    if suffix == ".png":
        return b"IEND" not in data[-32:]
    return False


def read_gray(path: Path) -> np.ndarray:
    """Read an image as grayscale uint8; a corrupt, truncated or empty file is an ImageError."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ImageError(f"cannot read image {path}: {exc.strerror or exc}") from exc
    if not data:
        raise ImageError(f"image {path} is empty (0 bytes)")
    if _truncated(data, path.suffix.lower()):
        raise ImageError(f"image {path} is truncated or corrupt (no end-of-image marker)")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise ImageError(f"image {path} is corrupt or not an image")
    return np.asarray(img)


@dataclass(frozen=True)
class DetectedImages:
    """Board detections for a list of images, all of one size."""

    paths: tuple[Path, ...]
    detections: tuple[Detection | None, ...]
    image_size: tuple[int, int]

    @property
    def found(self) -> int:
        return sum(d is not None for d in self.detections)


def detect_images(
    board: BoardSpec, paths: Sequence[Path], workers: int | None = None
) -> DetectedImages:
    """Read and detect ``board`` in every image, in parallel threads (OpenCV drops the GIL)."""

    def one(path: Path) -> tuple[tuple[int, int], Detection | None]:
        gray = read_gray(path)
        return (gray.shape[1], gray.shape[0]), board.detect(gray)

    n_workers = workers or min(len(paths), os.cpu_count() or 1)
    with ThreadPoolExecutor(max_workers=max(1, n_workers)) as pool:
        results = list(pool.map(one, paths))
    sizes = [size for size, _ in results]
    first = sizes[0]
    for path, size in zip(paths, sizes, strict=True):
        if size != first:
            raise ImageError(
                f"image {path} is {size[0]}x{size[1]} but {paths[0].name} is "
                f"{first[0]}x{first[1]}; one camera's images must share one size"
            )
    detected = DetectedImages(tuple(paths), tuple(d for _, d in results), first)
    if detected.found == 0:
        hint = board.diagnose_missing([read_gray(p) for p in paths[:3]])
        raise BoardNotFoundError(f"no {board} found in any of {len(paths)} images; {hint}")
    return detected
