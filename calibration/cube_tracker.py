"""Stereo trackers for the marker cube and the seam's end plates, in the deploy loop's style.

Once per control period the loop hands over the latest frame pair and its capture time, and
asks for the estimate at the command time::

    tracker = StereoCubeTracker(rig, base_T_cam=base_T_left, cube=MarkerCube())
    est = tracker.observe(left_bgr, right_bgr, capture_time_s)   # CubeEstimate, base frame
    est = tracker.predict(command_time_s)                        # latency compensation
    if est.valid: ... est.position_m, est.yaw_rad, est.blind_s ...

Inside ``observe``: ArUco detection in both images (around the last sighting first) → every face
id seen in both images is undistorted + triangulated (its four corners) → a rigid square is
fitted → the face gives the cube centre (face centre minus half the side along its normal) and
the yaw mod 90° (:func:`calibration.cube.centre_and_yaw`) → faces are averaged → the position
goes through the same ``KalmanTracker`` as the target plate, in the target's quiet
configuration (:data:`CUBE_TRACKER_CONFIG`).

During a grasp the fingers hide the cube: that is the normal case, not a fault. The tracker then
coasts on its prediction and reports ``blind_s``, the time since a face was last accepted. When
it sees the cube again after more than ``reacquire_after_s`` blind, it starts a new track from
that sighting, because a hidden cube is usually a cube being moved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from calibration.boards import aruco_dictionary, canonical_dictionary_name
from calibration.cube import (
    CubeFit,
    FaceObservation,
    MarkerCube,
    SeamMarkers,
    fuse_faces,
    mean_yaw,
    wrap_yaw,
)
from calibration.errors import CalibrationError, ConfigError
from calibration.kalman import Estimate, KalmanTracker, TrackerConfig
from calibration.markers import Marker, Roi, clip_roi, marker_corners, to_gray
from calibration.perception import StereoMarkerTracker
from calibration.triangulate import StereoRig, fit_marker_pose

# The deploy target plate's quiet model (``sim2real.deploy.perception``): a still object,
# smoothed hard, that coasts indefinitely (the tracker reports how long, the caller decides).
CUBE_TRACKER_CONFIG = TrackerConfig(
    model="cv",
    manoeuvre_std=None,
    process_std=0.001,
    init_velocity_std_mps=0.001,
    max_coast_s=3600.0,
)


@dataclass(frozen=True, eq=False)
class CubeEstimate:
    """The cube at ``timestamp_s`` in the base frame.

    ``valid`` is False until a face has been seen (then ``blind_s`` is ``inf`` and ``reason``
    says why). ``yaw_rad`` is about base z, in [-π/4, π/4): a cube looks the same every 90°.
    ``faces_seen`` lists the face ids measured this frame pair (empty when nothing was seen and
    from ``predict``); a measurement the Kalman gate rejects still lists its faces, while
    ``blind_s`` counts from the last accepted one.
    """

    timestamp_s: float
    position_m: np.ndarray  # (3,), NaN when not valid
    yaw_rad: float  # NaN when not valid
    valid: bool
    blind_s: float
    faces_seen: tuple[int, ...]
    status: str  # the KalmanTracker's: initialised, updated, rejected, predicted, ...
    position_std_m: np.ndarray  # (3,) 1σ of the filtered position
    reason: str = ""

    @property
    def coasting(self) -> bool:
        return self.valid and self.blind_s > 0.0


class SmallMarkerDetector:
    """ArUco detection tuned for markers of 10–20 px, the cube's faces at half a metre.

    A 20 mm face at 0.6 m is about 15 px wide, and foreshortened at 45° its modules are under
    2 px: OpenCV's defaults find a cube face in about 82 % of such rendered images. Upscaling the
    searched region ``upscale`` × (cubic) before detection, with a finer adaptive threshold,
    finds one in all of them (``bench/cube_perception.py``); the corners come back in full-image
    pixels. Searching a region of interest keeps the upscaled image small.
    """

    def __init__(self, dictionary: str = "DICT_4X4_50", upscale: float = 1.5) -> None:
        if not (math.isfinite(upscale) and 1.0 <= upscale <= 4.0):
            raise ConfigError(f"upscale must be in [1, 4], got {upscale}")
        self.dictionary = canonical_dictionary_name(dictionary)
        self.upscale = upscale
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        params.cornerRefinementWinSize = 4
        params.adaptiveThreshWinSizeMin = 3
        params.adaptiveThreshWinSizeMax = 15
        params.adaptiveThreshWinSizeStep = 4
        params.minMarkerPerimeterRate = 0.01
        params.polygonalApproxAccuracyRate = 0.05
        params.perspectiveRemovePixelPerCell = 8
        params.perspectiveRemoveIgnoredMarginPerCell = 0.2
        params.minCornerDistanceRate = 0.02
        self._detector = cv2.aruco.ArucoDetector(aruco_dictionary(self.dictionary), params)

    def detect(self, image: np.ndarray, roi: Roi | None = None) -> list[Marker]:
        """All markers in ``image`` (or only inside ``roi``), corners in full-image pixels."""
        offset = np.zeros(2)
        if roi is not None:
            box = clip_roi(roi, image.shape)
            if box is None:
                return []
            image = image[box[1] : box[3], box[0] : box[2]]
            offset = np.array(box[:2], np.float64)
        gray = to_gray(image)
        s = self.upscale
        if s != 1.0:
            gray = cv2.resize(gray, None, fx=s, fy=s, interpolation=cv2.INTER_CUBIC)
        corners, ids, _ = self._detector.detectMarkers(gray)
        if ids is None:
            return []
        # Pixel centres: x_full = (x_up + 0.5) / s - 0.5 for a resize that maps pixel areas.
        return [
            Marker(int(i), (np.asarray(c, np.float64).reshape(4, 2) + 0.5) / s - 0.5 + offset)
            for c, i in zip(corners, ids.ravel(), strict=True)
        ]


def _unique_faces(found: list[Marker], face_ids: frozenset[int]) -> list[Marker]:
    """The cube's face markers found exactly once (a repeated id is ambiguous)."""
    ids = [m.id for m in found]
    return [m for m in found if m.id in face_ids and ids.count(m.id) == 1]


def _area_px(corners_px: np.ndarray) -> float:
    c = np.asarray(corners_px, np.float64).reshape(-1, 2)
    x, y = c[:, 0], c[:, 1]
    return 0.5 * abs(float(x @ np.roll(y, -1) - y @ np.roll(x, -1)))


def _rigid_inverse(a_T_b: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = a_T_b[:3, :3].T
    T[:3, 3] = -a_T_b[:3, :3].T @ a_T_b[:3, 3]
    return T


def _pose(params: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(params[:3])[0]
    T[:3, 3] = params[3:]
    return T


@dataclass(frozen=True, eq=False)
class CornerModel:
    """The detected corners of one image and their cube-frame model: a face centre plus an
    offset scaled by the apparent marker size (the refinement's 7th parameter)."""

    side: int  # 0 left, 1 right
    centres: np.ndarray  # (4N, 3) cube frame
    offsets: np.ndarray  # (4N, 3)
    observed_px: np.ndarray  # (4N, 2)


def corner_models(
    cube: MarkerCube, markers: tuple[list[Marker], list[Marker]]
) -> list[CornerModel]:
    models = []
    for side, found in enumerate(markers):
        if found:
            corners = np.concatenate([cube.face_corners_m(m.id) for m in found])
            centres = np.repeat([cube.cube_T_face(m.id)[:3, 3] for m in found], 4, axis=0)
            observed = np.concatenate([m.corners_px for m in found])
            models.append(CornerModel(side, centres, corners - centres, observed))
    return models


def residual_and_jacobian(
    rig: StereoRig, models: list[CornerModel], params: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Reprojection residuals (2M,) in px of the cube ``params`` = [rvec (3), tvec (3) of
    ``left_T_cube``, marker scale] and their Jacobian (2M, 7), analytic: ``projectPoints`` gives
    d(uv)/d(rvec, tvec) (d/dtvec is also d/d(point) in the camera frame, which gives the scale
    column) and ``composeRT`` chains the right camera's pose through ``right_T_left``."""
    rvec, tvec, scale = params[:3].reshape(3, 1), params[3:6].reshape(3, 1), float(params[6])
    rvec_rl = cv2.Rodrigues(np.ascontiguousarray(rig.R))[0]
    residuals, jacobians = [], []
    for model in models:
        cam = rig.left if model.side == 0 else rig.right
        if model.side == 0:
            rv, tv = rvec, tvec
        else:
            rv, tv, dr_dr, dr_dt, _, _, dt_dr, dt_dt, _, _ = cv2.composeRT(
                rvec, tvec, rvec_rl, rig.T.reshape(3, 1)
            )
        points = model.centres + scale * model.offsets
        uv, jac = cv2.projectPoints(points, rv, tv, cam.K, cam.dist)
        residuals.append(uv.reshape(-1, 2) - model.observed_px)
        j_r, j_t = jac[:, 0:3], jac[:, 3:6]
        d_point = j_t.reshape(-1, 2, 3)  # d(uv)/d(point in this camera's frame)
        R = cv2.Rodrigues(rv)[0]
        j_s = np.einsum("nij,nj->ni", d_point, model.offsets @ R.T)
        if model.side == 1:
            j_r, j_t = j_r @ dr_dr + j_t @ dt_dr, j_r @ dr_dt + j_t @ dt_dt
        jacobians.append(np.hstack([j_r, j_t, j_s.reshape(-1, 1)]))
    return np.concatenate(residuals).ravel(), np.vstack(jacobians)


def refine_cube_pose(
    rig: StereoRig,
    cube: MarkerCube,
    markers: tuple[list[Marker], list[Marker]],
    left_T_cube: np.ndarray,
    iterations: int = 10,
    free_scale: bool = True,
) -> tuple[np.ndarray, float]:
    """Refine ``left_T_cube`` (4, 4) so the cube's face corners reproject onto the detected
    corners in both images (Gauss–Newton on rotation vector, translation and the markers'
    apparent size, :func:`residual_and_jacobian`).

    Triangulating each corner alone leaves millimetres of depth noise per corner at half a
    metre (0.5 px of disparity is ~4 mm there), so a single face's normal is off by degrees;
    fitting the rigid cube to every corner in both images, faces seen by one camera included,
    is the least-squares pose. The apparent marker size is free (a 7th parameter) because blur
    and thresholding move detected corners inwards by a fraction of a pixel: with the printed
    size imposed, a 15 px marker read 1 % small would put the cube ~6 mm too far; free, depth
    comes from the disparity. Corners from one camera only carry no disparity: there the printed
    size must stay imposed (``free_scale=False``) or depth is unobservable. Returns the pose and
    the RMS reprojection error (px).
    """
    models = corner_models(cube, markers)
    rvec = cv2.Rodrigues(np.ascontiguousarray(left_T_cube[:3, :3]))[0].ravel()
    params = np.concatenate([rvec, left_T_cube[:3, 3], [1.0]])

    def residuals(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, J = residual_and_jacobian(rig, models, p)
        if not free_scale:
            J[:, 6] = 0.0  # the scale's step is then zero: the printed size holds
        return r, J

    r, J = residuals(params)
    for _ in range(iterations):
        JtJ = J.T @ J
        # cv2.solve, not np.linalg: a 7x7 system must not wait on BLAS threads in a busy loop.
        ok, delta = cv2.solve(
            JtJ + 1e-9 * np.trace(JtJ) * np.eye(len(params)), -J.T @ r, flags=cv2.DECOMP_CHOLESKY
        )
        if not ok:
            break
        delta = delta.ravel()
        trial = params + delta
        r_trial, J_trial = residuals(trial)
        if float(r_trial @ r_trial) >= float(r @ r):
            break
        params, r, J = trial, r_trial, J_trial
        if np.max(np.abs(delta[:3])) < 1e-7 and np.max(np.abs(delta[3:6])) < 1e-8:
            break
    rms_px = float(np.sqrt(np.mean(np.sum(r.reshape(-1, 2) ** 2, axis=1))))
    return _pose(params[:6]), rms_px


def yaw_of(base_R_cube: np.ndarray) -> float:
    """The cube's yaw about base z, mod 90°: the heading of a cube axis that is not the most
    vertical one (whichever face the cube rests on)."""
    up = int(np.argmax(np.abs(base_R_cube[2])))
    edge = base_R_cube[:, (up + 1) % 3]
    return wrap_yaw(math.atan2(edge[1], edge[0]))


def _union_roi(markers: list[Marker], margin: float) -> Roi:
    boxes = np.array([m.roi(margin) for m in markers])
    return (
        int(boxes[:, 0].min()),
        int(boxes[:, 1].min()),
        int(boxes[:, 2].max()),
        int(boxes[:, 3].max()),
    )


def _check_frame(name: str, frame: np.ndarray, image_size: tuple[int, int]) -> None:
    if not isinstance(frame, np.ndarray) or frame.ndim not in (2, 3) or frame.dtype != np.uint8:
        shape = getattr(frame, "shape", None)
        raise ConfigError(
            f"the {name} frame must be a uint8 image (H, W[, 3]), got {type(frame).__name__} "
            f"with shape {shape}"
        )
    size = (frame.shape[1], frame.shape[0])
    if size != tuple(image_size):
        raise CalibrationError(
            f"the {name} camera delivers {size[0]}x{size[1]} frames but the stereo calibration "
            f"is for {image_size[0]}x{image_size[1]}"
        )


class StereoCubeTracker:
    """Detect → triangulate faces → fuse → base frame → Kalman filter, for a :class:`MarkerCube`.

    ``base_T_cam`` maps the left camera frame to the arm base. A face counts only when its id is
    found once in each image, its corners lie within ``max_epipolar_px`` of their epipolar lines
    and the triangulated corners fit a square of the printed side to ``max_fit_rms_m``. With
    ``refine`` (default) the whole cube is then fitted to every detected corner in both images
    (:func:`refine_cube_pose`); a fit worse than ``max_reprojection_px`` (a marker glued turned,
    a false detection) falls back to the per-face average, and a frame pair whose faces disagree
    there on the centre by more than ``max_spread_m`` is a miss. With ``single_view`` (default),
    a pair with no face in both images is fitted from the faces each camera sees alone
    (:meth:`_single_view`): the arm descending on the cube usually hides it from one camera.
    """

    def __init__(
        self,
        rig: StereoRig,
        base_T_cam: np.ndarray | None = None,
        cube: MarkerCube | None = None,
        tracker: TrackerConfig | None = None,
        roi_margin: float = 2.0,
        max_epipolar_px: float = 3.0,
        max_fit_rms_m: float = 0.006,
        max_spread_m: float = 0.006,
        reacquire_after_s: float = 0.25,
        yaw_time_constant_s: float = 0.1,
        upscale: float = 1.5,
        refine: bool = True,
        max_reprojection_px: float = 1.5,
        full_search_every: int = 4,
        single_view: bool = True,
    ) -> None:
        self.rig = rig
        self.base_T_cam = np.eye(4) if base_T_cam is None else np.asarray(base_T_cam, np.float64)
        if self.base_T_cam.shape != (4, 4):
            raise ConfigError(f"base_T_cam must be 4x4, got {self.base_T_cam.shape}")
        for name, value in (
            ("max_epipolar_px", max_epipolar_px),
            ("max_fit_rms_m", max_fit_rms_m),
            ("max_spread_m", max_spread_m),
            ("max_reprojection_px", max_reprojection_px),
        ):
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"{name} must be a positive number, got {value!r}")
        if roi_margin < 0 or reacquire_after_s < 0 or yaw_time_constant_s < 0:
            raise ConfigError("roi_margin, reacquire_after_s and yaw_time_constant_s must be ≥ 0")
        self._cam_T_base = _rigid_inverse(self.base_T_cam)
        self.cube = cube or MarkerCube()
        self.config = tracker or CUBE_TRACKER_CONFIG
        self.roi_margin = roi_margin
        self.max_epipolar_px = max_epipolar_px
        self.max_fit_rms_m = max_fit_rms_m
        self.max_spread_m = max_spread_m
        self.reacquire_after_s = reacquire_after_s
        self.yaw_time_constant_s = yaw_time_constant_s
        if full_search_every < 1:
            raise ConfigError(f"full_search_every must be ≥ 1, got {full_search_every}")
        self.full_search_every = full_search_every
        self.refine = refine
        self.single_view = single_view
        self.max_reprojection_px = max_reprojection_px
        self.detector = SmallMarkerDetector(self.cube.dictionary, upscale)
        self._face_ids = frozenset(self.cube.face_ids)
        self._model_corners = marker_corners(self.cube.marker_m)
        self.reset()

    def reset(self) -> None:
        """Forget the track (a new episode: the cube was placed anew)."""
        self.tracker = KalmanTracker(self.config)
        self._last: list[list[Marker]] = [[], []]  # the previous pair's markers
        self._sighting: list[list[Marker]] = [[], []]  # the last measured pair's markers
        self._misses = 0  # pairs without a measurement since the last one
        self._last_seen_s: float | None = None
        self._last_capture_s: float | None = None
        self._yaw_rad = math.nan
        self._last_estimate: CubeEstimate | None = None
        self.last_fit: CubeFit | None = None
        self.frames_seen = 0
        self.frames_observed = 0

    # ------------------------------------------------------------------ measurement
    def _regions(self, side: int) -> list[Roi]:
        """Where to look first: around the last pair's markers, else around the last sighting
        (grown: a hidden cube is often moved)."""
        if self.roi_margin <= 0:
            return []
        if self._last[side]:
            return [_union_roi(self._last[side], self.roi_margin)]
        if self._sighting[side]:
            return [_union_roi(self._sighting[side], 2.0 * self.roi_margin)]
        return []

    def _find(self, side: int, frame: np.ndarray, full: bool) -> tuple[list[Marker], bool]:
        """The cube's face markers in one image, and whether the whole image was searched."""
        for roi in self._regions(side):
            found = [m for m in self.detector.detect(frame, roi) if m.id in self._face_ids]
            if found:
                return found, False
        if not full:
            return [], False
        return self._detect_all(frame), True

    def _detect_all(self, frame: np.ndarray) -> list[Marker]:
        return [m for m in self.detector.detect(frame) if m.id in self._face_ids]

    def _face(self, left: Marker, right: Marker) -> FaceObservation | None:
        epipolar = float(np.max(self.rig.epipolar_errors_px(left.corners_px, right.corners_px)))
        if epipolar > self.max_epipolar_px:
            return None
        cam_corners = self.rig.triangulate(left.corners_px, right.corners_px)
        cam_T_marker, fit_rms = fit_marker_pose(cam_corners, self._model_corners)
        if not fit_rms <= self.max_fit_rms_m:
            return None
        return FaceObservation(left.id, self.base_T_cam @ cam_T_marker, fit_rms)

    def measure_markers(self, left: list[Marker], right: list[Marker]) -> CubeFit | None:
        """Fuse the faces found in both images (detections from any source), or ``None``."""
        by_id_l: dict[int, list[Marker]] = {}
        by_id_r: dict[int, list[Marker]] = {}
        for markers, by_id in ((left, by_id_l), (right, by_id_r)):
            for m in markers:
                if m.id in self._face_ids:
                    by_id.setdefault(m.id, []).append(m)
        faces = []
        for marker_id in sorted(set(by_id_l) & set(by_id_r)):
            if len(by_id_l[marker_id]) == 1 and len(by_id_r[marker_id]) == 1:  # else ambiguous
                face = self._face(by_id_l[marker_id][0], by_id_r[marker_id][0])
                if face is not None:
                    faces.append(face)
        if not faces:
            return self._single_view(left, right) if self.single_view else None
        stereo = fuse_faces(self.cube, faces)
        if self.refine:
            best = min(faces, key=lambda f: f.fit_rms_m)
            cam_T_base = self._cam_T_base
            left_T_cube = (
                cam_T_base
                @ best.base_T_marker
                @ _rigid_inverse(self.cube.cube_T_face(best.marker_id))
            )
            left_T_cube[:3, 3] = cam_T_base[:3, :3] @ stereo.position_m + cam_T_base[:3, 3]
            used = (
                [m for m in left if m.id in self._face_ids],
                [m for m in right if m.id in self._face_ids],
            )
            left_T_cube, rms_px = refine_cube_pose(self.rig, self.cube, used, left_T_cube)
            if rms_px <= self.max_reprojection_px:
                base_T_cube = self.base_T_cam @ left_T_cube
                return replace(
                    stereo,
                    position_m=base_T_cube[:3, 3].copy(),
                    yaw_rad=yaw_of(base_T_cube[:3, :3]),
                    face_ids=tuple(sorted({m.id for m in used[0] + used[1]})),
                    reprojection_px=rms_px,
                )
        return stereo if stereo.spread_m <= self.max_spread_m else None

    def _single_view(self, left: list[Marker], right: list[Marker]) -> CubeFit | None:
        """The cube from faces that no one camera pair shares: the arm often hides the cube from
        one camera while the other still sees a face. Seed from the largest face's planar pose
        (IPPE: both of its mirror solutions), then fit the rigid cube to every face corner in
        both images; one camera alone keeps the printed size (no disparity to say depth)."""
        used = (
            _unique_faces(left, self._face_ids),
            _unique_faces(right, self._face_ids),
        )
        seen = [(side, m) for side in (0, 1) for m in used[side]]
        if not seen:
            return None
        side, seed = max(seen, key=lambda sm: _area_px(sm[1].corners_px))
        cam = self.rig.left if side == 0 else self.rig.right
        n, rvecs, tvecs, _ = cv2.solvePnPGeneric(
            self._model_corners,
            np.ascontiguousarray(seed.corners_px, np.float64),
            cam.K,
            cam.dist,
            flags=cv2.SOLVEPNP_IPPE_SQUARE,
        )
        left_T_cam = np.eye(4)
        if side == 1:
            left_T_cam[:3, :3], left_T_cam[:3, 3] = self.rig.R.T, -self.rig.R.T @ self.rig.T
        face_T_cube = _rigid_inverse(self.cube.cube_T_face(seed.id))
        both = bool(used[0]) and bool(used[1])
        best: tuple[np.ndarray, float] | None = None
        for rvec, tvec in zip(rvecs[:n], tvecs[:n], strict=True):
            cam_T_marker = _pose(np.concatenate([np.ravel(rvec), np.ravel(tvec)]))
            start = left_T_cam @ cam_T_marker @ face_T_cube
            pose, rms_px = refine_cube_pose(self.rig, self.cube, used, start, free_scale=both)
            if best is None or rms_px < best[1]:
                best = (pose, rms_px)
        if best is None or not best[1] <= self.max_reprojection_px:
            return None
        base_T_cube = self.base_T_cam @ best[0]
        return CubeFit(
            base_T_cube[:3, 3].copy(),
            yaw_of(base_T_cube[:3, :3]),
            tuple(sorted({m.id for m in used[0] + used[1]})),
            0.0,
            math.nan,  # no face was triangulated
            best[1],
        )

    def measure(self, left_bgr: np.ndarray, right_bgr: np.ndarray) -> CubeFit | None:
        """The cube's raw (unfiltered) centre and yaw from one frame pair, or ``None``.

        While the cube is lost after a sighting, only every ``full_search_every``-th pair is
        searched whole (upscaled full frames are the tracker's dearest step); the others look
        around the last sighting.
        """
        full = not any(self._sighting) or self._misses % self.full_search_every == 0
        (left, full_l), (right, full_r) = (
            self._find(0, left_bgr, full),
            self._find(1, right_bgr, full),
        )
        fit = self.measure_markers(left, right)
        if fit is None and full and not (full_l and full_r):  # a region may have cut a face off
            if not full_l:
                left = self._detect_all(left_bgr)
            if not full_r:
                right = self._detect_all(right_bgr)
            fit = self.measure_markers(left, right)
        self._misses = 0 if fit is not None else self._misses + 1
        if fit is not None:
            self._sighting = [left, right]
        self._last = [left, right]
        return fit

    # ------------------------------------------------------------------ tracking
    def _smooth_yaw(self, yaw_rad: float, dt_s: float) -> None:
        if math.isnan(self._yaw_rad) or self.yaw_time_constant_s == 0:
            self._yaw_rad = yaw_rad
            return
        alpha = 1.0 - math.exp(-dt_s / self.yaw_time_constant_s) if dt_s > 0 else 0.0
        self._yaw_rad = mean_yaw(np.array([self._yaw_rad, yaw_rad]), np.array([1 - alpha, alpha]))

    def _result(self, est: Estimate, faces: tuple[int, ...]) -> CubeEstimate:
        t = est.timestamp_s
        if not est.valid or self._last_seen_s is None:
            nan3 = np.full(3, np.nan)
            reason = (
                f"cube never seen: no face marker ({self.cube.dictionary} ids "
                f"{list(self.cube.face_ids)}) found in both images in {self.frames_observed} "
                "frame pair(s)"
                if self._last_seen_s is None
                else f"cube track lost ({est.status})"
            )
            return CubeEstimate(
                t, nan3, math.nan, False, math.inf, faces, est.status, nan3.copy(), reason
            )
        return CubeEstimate(
            t,
            est.position_m,
            self._yaw_rad,
            True,
            max(0.0, t - self._last_seen_s),
            faces,
            est.status,
            est.position_std_m,
        )

    def observe(
        self, left_bgr: np.ndarray, right_bgr: np.ndarray, capture_time_s: float
    ) -> CubeEstimate:
        """Measure the frame pair captured at ``capture_time_s`` and filter.

        The same pair handed over twice (a free-running camera that has no new frame yet) is
        not measured again: its estimate is returned, so no measurement is counted twice.
        """
        if not math.isfinite(capture_time_s) or (
            self._last_capture_s is not None and capture_time_s < self._last_capture_s
        ):
            raise ConfigError(
                f"capture time {capture_time_s!r} s is before the previous frame pair's "
                f"({self._last_capture_s} s); timestamps must not go backwards"
            )
        if capture_time_s == self._last_capture_s:
            assert self._last_estimate is not None
            return self._last_estimate
        if self._last_capture_s is None:
            _check_frame("left", left_bgr, self.rig.left.image_size)
            _check_frame("right", right_bgr, self.rig.right.image_size)
        self.frames_observed += 1
        fit = self.measure(left_bgr, right_bgr)
        self.last_fit = fit
        if fit is None:
            est = self.tracker.predict(capture_time_s)
            faces: tuple[int, ...] = ()
        else:
            blind = (
                capture_time_s - self._last_seen_s if self._last_seen_s is not None else math.inf
            )
            if self._last_seen_s is not None and blind > self.reacquire_after_s:
                self.tracker.reset()  # hidden long enough to have been moved: a new track
            est = self.tracker.update(fit.position_m, capture_time_s)
            faces = fit.face_ids
            if est.status in ("initialised", "updated", "reinitialised"):
                dt = 0.0 if self._last_seen_s is None else capture_time_s - self._last_seen_s
                if est.status != "updated":
                    self._yaw_rad = math.nan  # a new track: take the yaw as measured
                self._smooth_yaw(fit.yaw_rad, dt)
                self._last_seen_s = capture_time_s
                self.frames_seen += 1
        self._last_capture_s = capture_time_s
        result = self._result(est, faces)
        self._last_estimate = result
        return result

    def predict(self, command_time_s: float) -> CubeEstimate:
        """The filtered cube extrapolated to ``command_time_s``; the state is unchanged."""
        return self._result(self.tracker.predict_at(command_time_s), ())


@dataclass(frozen=True, eq=False)
class SeamEstimate:
    """The seam's two ends (3,) in the base frame, from the two plates' filtered centres."""

    timestamp_s: float
    start_m: np.ndarray
    end_m: np.ndarray
    valid: bool
    blind_s: float  # since both plates were last seen in the same frame pair
    reason: str = ""


class StereoSeamTracker:
    """Two :class:`~calibration.perception.StereoMarkerTracker` (the seam's start and end plates,
    quiet model) → :meth:`SeamMarkers.seam_ends`. A plate hidden by the arm coasts."""

    def __init__(
        self,
        rig: StereoRig,
        base_T_cam: np.ndarray | None = None,
        seam: SeamMarkers | None = None,
        tracker: TrackerConfig | None = None,
    ) -> None:
        self.seam = seam or SeamMarkers()
        cfg = tracker or CUBE_TRACKER_CONFIG
        self.plates = tuple(
            StereoMarkerTracker(
                rig,
                base_T_cam=base_T_cam,
                marker_id=marker_id,
                dictionary=self.seam.dictionary,
                marker_length_m=self.seam.marker_m,
                tracker=cfg,
            )
            for marker_id in (self.seam.start_id, self.seam.end_id)
        )
        self._last_seen_s: float | None = None
        self._last: SeamEstimate | None = None

    def observe(
        self, left_bgr: np.ndarray, right_bgr: np.ndarray, capture_time_s: float
    ) -> SeamEstimate:
        """Measure and filter both plates; the same pair handed over twice is measured once."""
        if self._last is not None and capture_time_s == self._last.timestamp_s:
            return self._last
        ests = [p.observe(left_bgr, right_bgr, capture_time_s) for p in self.plates]
        if all(p.last_measurement is not None for p in self.plates):
            self._last_seen_s = capture_time_s
        self._last = self._result(ests, capture_time_s)
        return self._last

    def predict(self, command_time_s: float) -> SeamEstimate:
        return self._result([p.predict(command_time_s) for p in self.plates], command_time_s)

    def _result(self, ests: list[Estimate], t: float) -> SeamEstimate:
        nan3 = np.full(3, np.nan)
        if not all(e.valid for e in ests) or self._last_seen_s is None:
            ids = [self.seam.start_id, self.seam.end_id]
            missing = [i for i, e in zip(ids, ests, strict=True) if not e.valid]
            return SeamEstimate(
                t, nan3, nan3.copy(), False, math.inf,
                f"seam plate(s) {missing or ids} ({self.seam.dictionary}) not yet seen in both images",
            )  # fmt: skip
        try:
            start, end = self.seam.seam_ends(ests[0].position_m, ests[1].position_m)
        except ConfigError as exc:
            return SeamEstimate(t, nan3, nan3.copy(), False, math.inf, str(exc))
        return SeamEstimate(t, start, end, True, max(0.0, t - self._last_seen_s))
