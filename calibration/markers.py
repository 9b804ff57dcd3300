"""Marker detection: ArUco with sub-pixel corners (default) or a colour blob.

ArUco gives four corners with ids, so the two cameras agree on which corner is which and the
marker's full pose can be recovered; a colour blob gives only a centroid. Both detectors accept a
region of interest so a tracker can search only around the last detection (about 6× faster at
640×480, measured in ``bench/perception.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from calibration.boards import aruco_dictionary, canonical_dictionary_name
from calibration.errors import ConfigError

# A box (x0, y0, x1, y1) in pixels, x1/y1 exclusive.
Roi = tuple[int, int, int, int]


def to_gray(image: np.ndarray) -> np.ndarray:
    """BGR, BGRA or grayscale uint8 → grayscale uint8 (no copy when already gray)."""
    if image.ndim == 2:
        return image
    code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
    return cv2.cvtColor(image, code)


def clip_roi(roi: Roi, shape: tuple[int, ...]) -> Roi | None:
    """Intersect ``roi`` with an image of ``shape``; ``None`` when nothing is left."""
    height, width = shape[:2]
    x0, y0 = max(0, roi[0]), max(0, roi[1])
    x1, y1 = min(width, roi[2]), min(height, roi[3])
    return (x0, y0, x1, y1) if x1 - x0 >= 8 and y1 - y0 >= 8 else None


@dataclass(frozen=True, eq=False)
class Marker:
    """One ArUco marker: ``corners_px`` (4,2) in ArUco order (top-left, top-right,
    bottom-right, bottom-left *of the marker*, whatever its rotation in the image)."""

    id: int
    corners_px: np.ndarray

    @property
    def centre_px(self) -> np.ndarray:
        return np.asarray(self.corners_px.mean(axis=0))

    @property
    def side_px(self) -> float:
        return float(
            np.linalg.norm(np.roll(self.corners_px, -1, axis=0) - self.corners_px, axis=1).mean()
        )

    def roi(self, margin: float) -> Roi:
        """A box around the marker grown by ``margin`` × its side on every side."""
        pad = margin * self.side_px
        lo = np.floor(self.corners_px.min(axis=0) - pad).astype(int)
        hi = np.ceil(self.corners_px.max(axis=0) + pad).astype(int) + 1
        return int(lo[0]), int(lo[1]), int(hi[0]), int(hi[1])


def marker_corners(marker_length_m: float) -> np.ndarray:
    """The four corners (4,3) in the marker frame, in ArUco's order (TL, TR, BR, BL).

    The frame is OpenCV's: origin at the centre, x right, y up, z out of the marker.
    """
    h = marker_length_m / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


class ArucoMarkerDetector:
    """``cv2.aruco.ArucoDetector`` (OpenCV ≥ 4.7 API) with sub-pixel corner refinement."""

    def __init__(self, dictionary: str = "DICT_4X4_50", subpixel: bool = True) -> None:
        self.dictionary = canonical_dictionary_name(dictionary)
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = (
            cv2.aruco.CORNER_REFINE_SUBPIX if subpixel else cv2.aruco.CORNER_REFINE_NONE
        )
        params.cornerRefinementWinSize = 4
        self._detector = cv2.aruco.ArucoDetector(aruco_dictionary(self.dictionary), params)

    def detect(self, image: np.ndarray, roi: Roi | None = None) -> list[Marker]:
        """All markers in ``image`` (or only inside ``roi``), corners in full-image pixels."""
        offset = np.zeros(2, np.float32)
        if roi is not None:  # crop before the colour conversion: only the ROI is converted
            box = clip_roi(roi, image.shape)
            if box is None:
                return []
            image = image[box[1] : box[3], box[0] : box[2]]
            offset = np.array(box[:2], np.float32)
        corners, ids, _ = self._detector.detectMarkers(to_gray(image))
        if ids is None:
            return []
        return [
            Marker(int(i), np.asarray(c, np.float64).reshape(4, 2) + offset)
            for c, i in zip(corners, ids.ravel(), strict=True)
        ]

    def find(self, image: np.ndarray, marker_id: int, roi: Roi | None = None) -> Marker | None:
        """The marker with ``marker_id``; ``None`` if absent (or seen twice: ambiguous)."""
        found = [m for m in self.detect(image, roi) if m.id == marker_id]
        return found[0] if len(found) == 1 else None


@dataclass(frozen=True, eq=False)
class Blob:
    centre_px: np.ndarray  # (2,) sub-pixel centroid
    area_px: int

    def roi(self, margin: float) -> Roi:
        side = float(np.sqrt(self.area_px))
        pad = (0.5 + margin) * side
        x, y = self.centre_px
        return int(x - pad), int(y - pad), int(np.ceil(x + pad)) + 1, int(np.ceil(y + pad)) + 1


class ColorBlobDetector:
    """The largest blob inside an HSV range (OpenCV hue 0–179; ``low_hsv[0] > high_hsv[0]``
    wraps around red)."""

    def __init__(
        self,
        low_hsv: tuple[int, int, int],
        high_hsv: tuple[int, int, int],
        min_area_px: int = 20,
    ) -> None:
        for name, hsv in (("low_hsv", low_hsv), ("high_hsv", high_hsv)):
            if len(hsv) != 3 or not (
                0 <= hsv[0] <= 179 and 0 <= min(hsv[1:]) <= max(hsv[1:]) <= 255
            ):
                raise ConfigError(f"{name} must be (H 0-179, S 0-255, V 0-255), got {hsv}")
        if min_area_px < 1:
            raise ConfigError(f"min_area_px must be ≥ 1, got {min_area_px}")
        self.low = np.array(low_hsv, np.uint8)
        self.high = np.array(high_hsv, np.uint8)
        self.min_area_px = min_area_px

    def mask(self, bgr: np.ndarray) -> np.ndarray:
        if bgr.ndim != 3 or bgr.shape[2] != 3:
            raise ConfigError(f"colour blob detection needs a BGR image, got shape {bgr.shape}")
        hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)
        if self.low[0] <= self.high[0]:
            return cv2.inRange(hsv, self.low, self.high)
        upper = cv2.inRange(hsv, self.low, np.array([179, self.high[1], self.high[2]], np.uint8))
        lower = cv2.inRange(hsv, np.array([0, self.low[1], self.low[2]], np.uint8), self.high)
        return cv2.bitwise_or(upper, lower)

    def detect(self, bgr: np.ndarray, roi: Roi | None = None) -> Blob | None:
        offset = np.zeros(2)
        if roi is not None:
            box = clip_roi(roi, bgr.shape)
            if box is None:
                return None
            bgr = bgr[box[1] : box[3], box[0] : box[2]]
            offset = np.array(box[:2], np.float64)
        n, _, stats, centroids = cv2.connectedComponentsWithStats(self.mask(bgr), connectivity=8)
        if n <= 1:
            return None
        best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        area = int(stats[best, cv2.CC_STAT_AREA])
        if area < self.min_area_px:
            return None
        return Blob(np.asarray(centroids[best], np.float64) + offset, area)
