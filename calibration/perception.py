"""The deploy loop's perception step: two frames in, a filtered marker estimate out.

Each control period the loop calls :meth:`StereoMarkerTracker.observe` with the two frames and
their capture time::

    tracker = StereoMarkerTracker(StereoRig.load("calib/stereo.yaml"),
                                  base_T_cam=load_base_T_cam("calib/base_T_cam.yaml"),
                                  marker_id=0, dictionary="DICT_4X4_50", marker_length_m=0.03)
    est = tracker.observe(frame_left, frame_right, timestamp_s)   # Estimate, base frame
    if est.valid:
        target_m = tracker.predict(timestamp_s + latency_s).position_m

Inside: ArUco detection in both images (only around the last detection when there was one) →
the four corners triangulated → a rigid square fitted to them (position + orientation) → the
arm base frame through ``base_T_cam`` → ``KalmanTracker.update``; a frame without a consistent
detection only predicts. ``bench/perception.py`` measures one call at 640×480.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.errors import ConfigError
from calibration.kalman import Estimate, KalmanTracker, TrackerConfig
from calibration.markers import (
    ArucoMarkerDetector,
    Blob,
    ColorBlobDetector,
    Marker,
    marker_corners,
)
from calibration.triangulate import StereoRig, fit_marker_pose, quaternion_from_matrix


@dataclass(frozen=True, eq=False)
class MarkerMeasurement:
    """One frame pair's raw (unfiltered) marker pose in the base frame."""

    base_T_marker: np.ndarray  # noqa: N815 (frame names) 4×4
    left_corners_px: np.ndarray  # (4,2)
    right_corners_px: np.ndarray  # (4,2)
    fit_rms_m: float  # how far the triangulated corners are from a rigid square
    epipolar_px: float  # worst corner's distance to its epipolar line

    @property
    def position_m(self) -> np.ndarray:
        return self.base_T_marker[:3, 3].copy()

    @property
    def orientation_wxyz(self) -> np.ndarray:
        return quaternion_from_matrix(self.base_T_marker[:3, :3])


class StereoMarkerTracker:
    """Detect → triangulate → pose → base frame → Kalman filter, for one ArUco marker.

    ``base_T_cam`` maps the left camera frame to the arm base (identity: results stay in the
    left camera frame). ``marker_length_m`` is the printed side of the marker; ``None`` uses the
    triangulated side. ``roi_margin`` (× marker side) bounds the search around the last
    detection; 0 searches the full frame every time. A detection whose corners are more than
    ``max_epipolar_px`` off their epipolar lines is treated as a miss.
    """

    def __init__(
        self,
        rig: StereoRig,
        base_T_cam: np.ndarray | None = None,
        marker_id: int = 0,
        dictionary: str = "DICT_4X4_50",
        marker_length_m: float | None = None,
        tracker: TrackerConfig | None = None,
        roi_margin: float = 1.5,
        max_epipolar_px: float = 3.0,
    ) -> None:
        self.rig = rig
        self.base_T_cam = np.eye(4) if base_T_cam is None else np.asarray(base_T_cam, np.float64)
        if self.base_T_cam.shape != (4, 4):
            raise ConfigError(f"base_T_cam must be 4x4, got {self.base_T_cam.shape}")
        if marker_length_m is not None and not marker_length_m > 0:
            raise ConfigError(f"marker_length_m must be positive, got {marker_length_m}")
        if roi_margin < 0 or max_epipolar_px <= 0:
            raise ConfigError("roi_margin must be ≥ 0 and max_epipolar_px > 0")
        self.marker_id = marker_id
        self.marker_length_m = marker_length_m
        self.roi_margin = roi_margin
        self.max_epipolar_px = max_epipolar_px
        self.detector = ArucoMarkerDetector(dictionary)
        self.tracker = KalmanTracker(tracker)
        self._last: list[Marker | None] = [None, None]
        self.last_measurement: MarkerMeasurement | None = None

    def _find(self, side: int, frame: np.ndarray) -> Marker | None:
        last = self._last[side]
        marker = None
        if last is not None and self.roi_margin > 0:
            marker = self.detector.find(frame, self.marker_id, last.roi(self.roi_margin))
        if marker is None:
            marker = self.detector.find(frame, self.marker_id)
        self._last[side] = marker
        return marker

    def measure(self, frame_left: np.ndarray, frame_right: np.ndarray) -> MarkerMeasurement | None:
        """The marker's pose in the base frame from one frame pair, or ``None`` if not seen."""
        left = self._find(0, frame_left)
        right = self._find(1, frame_right)
        if left is None or right is None:
            return None
        epipolar = float(np.max(self.rig.epipolar_errors_px(left.corners_px, right.corners_px)))
        if epipolar > self.max_epipolar_px:
            return None
        cam_corners = self.rig.triangulate(left.corners_px, right.corners_px)
        length = self.marker_length_m
        if length is None:
            length = float(
                np.linalg.norm(np.roll(cam_corners, -1, axis=0) - cam_corners, axis=1).mean()
            )
        cam_T_marker, fit_rms = fit_marker_pose(cam_corners, marker_corners(length))
        return MarkerMeasurement(
            self.base_T_cam @ cam_T_marker,
            left.corners_px,
            right.corners_px,
            fit_rms,
            epipolar,
        )

    def observe(
        self, frame_left: np.ndarray, frame_right: np.ndarray, timestamp_s: float
    ) -> Estimate:
        """Measure and filter: update on a detection, predict-only on a miss."""
        meas = self.measure(frame_left, frame_right)
        self.last_measurement = meas
        if meas is None:
            return self.tracker.predict(timestamp_s)
        return self.tracker.update(meas.position_m, timestamp_s, meas.orientation_wxyz)

    def predict(self, timestamp_s: float) -> Estimate:
        """The filtered pose extrapolated to ``timestamp_s`` (latency compensation)."""
        return self.tracker.predict_at(timestamp_s)


class StereoBlobTracker:
    """The colour-blob alternative: the centroid of an HSV range in both images → triangulated
    → base frame → ``KalmanTracker``. Position only (a blob has no orientation)."""

    def __init__(
        self,
        rig: StereoRig,
        low_hsv: tuple[int, int, int],
        high_hsv: tuple[int, int, int],
        base_T_cam: np.ndarray | None = None,
        tracker: TrackerConfig | None = None,
        min_area_px: int = 20,
        roi_margin: float = 2.0,
        max_epipolar_px: float = 3.0,
    ) -> None:
        self.rig = rig
        self.base_T_cam = np.eye(4) if base_T_cam is None else np.asarray(base_T_cam, np.float64)
        if self.base_T_cam.shape != (4, 4):
            raise ConfigError(f"base_T_cam must be 4x4, got {self.base_T_cam.shape}")
        self.detector = ColorBlobDetector(low_hsv, high_hsv, min_area_px)
        self.tracker = KalmanTracker(tracker)
        self.roi_margin = roi_margin
        self.max_epipolar_px = max_epipolar_px
        self._last: list[Blob | None] = [None, None]
        self.last_position_m: np.ndarray | None = None

    def _find(self, side: int, frame: np.ndarray) -> Blob | None:
        last = self._last[side]
        blob = None
        if last is not None and self.roi_margin > 0:
            blob = self.detector.detect(frame, last.roi(self.roi_margin))
        if blob is None:
            blob = self.detector.detect(frame)
        self._last[side] = blob
        return blob

    def measure(self, frame_left: np.ndarray, frame_right: np.ndarray) -> np.ndarray | None:
        """Base-frame position (3,) of the blob centre, or ``None`` if not seen consistently."""
        left, right = self._find(0, frame_left), self._find(1, frame_right)
        if left is None or right is None:
            return None
        if self.rig.epipolar_errors_px(left.centre_px, right.centre_px)[0] > self.max_epipolar_px:
            return None
        cam_p = self.rig.triangulate(left.centre_px, right.centre_px)[0]
        return np.asarray(self.base_T_cam[:3, :3] @ cam_p + self.base_T_cam[:3, 3])

    def observe(
        self, frame_left: np.ndarray, frame_right: np.ndarray, timestamp_s: float
    ) -> Estimate:
        position = self.measure(frame_left, frame_right)
        self.last_position_m = position
        if position is None:
            return self.tracker.predict(timestamp_s)
        return self.tracker.update(position, timestamp_s)

    def predict(self, timestamp_s: float) -> Estimate:
        return self.tracker.predict_at(timestamp_s)
