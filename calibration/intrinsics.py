"""Monocular calibration with the quality checks of the good tools.

``calibrate_camera`` runs ``cv2.calibrateCameraExtended`` and then, until nothing is left to
reject, drops the worst view when its RMS is far above the median of the others. It reports
per-view errors, ±σ for every intrinsic, an odd/even cross-validation (two independent
calibrations, and each one's error on the other's views), a corner coverage map and warnings.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from calibration.boards import Detection
from calibration.camera import CameraModel
from calibration.errors import BoardNotFoundError, ConfigError, UnknownNameError

# Distortion models: name → (calibrateCamera flags, number of coefficients).
DIST_MODELS: dict[str, tuple[int, int]] = {
    "plumb_bob": (0, 5),
    "k1k2": (cv2.CALIB_FIX_K3, 5),
    "rational": (cv2.CALIB_RATIONAL_MODEL, 8),
    "none": (
        cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3,
        5,
    ),
}
# Order of stdDeviationsIntrinsics in calibrateCameraExtended.
_STD_NAMES = (
    "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6",
    "s1", "s2", "s3", "s4", "tau_x", "tau_y",
)  # fmt: skip
_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-9)


@dataclass(frozen=True)
class CalibrationConfig:
    """How hard to fit and what to reject.

    A view is rejected when its RMS exceeds both ``reject_factor`` × the median view RMS and
    ``reject_floor_px`` (so a tight set of good views is left alone), one view per round, while
    at least ``min_views`` remain.
    """

    dist_model: str = "plumb_bob"
    reject_outliers: bool = True
    reject_factor: float = 2.0
    reject_floor_px: float = 0.3
    min_views: int = 5
    warn_rms_px: float = 0.5
    warn_coverage: float = 0.5
    coverage_grid: tuple[int, int] = (8, 6)  # cells across, cells down

    def __post_init__(self) -> None:
        if self.dist_model not in DIST_MODELS:
            raise UnknownNameError("distortion model", self.dist_model, DIST_MODELS)
        if self.reject_factor <= 1.0:
            raise ConfigError(f"reject_factor must be > 1, got {self.reject_factor}")
        if self.reject_floor_px < 0 or self.warn_rms_px <= 0:
            raise ConfigError("reject_floor_px must be ≥ 0 and warn_rms_px > 0")
        if self.min_views < 3:
            raise ConfigError(f"min_views must be ≥ 3, got {self.min_views}")
        if not 0 <= self.warn_coverage <= 1:
            raise ConfigError(f"warn_coverage must be in [0, 1], got {self.warn_coverage}")
        if min(self.coverage_grid) < 1:
            raise ConfigError(f"coverage_grid must be positive, got {self.coverage_grid}")

    @property
    def flags(self) -> int:
        return DIST_MODELS[self.dist_model][0]

    def initial_dist(self) -> np.ndarray:
        return np.zeros(DIST_MODELS[self.dist_model][1])


@dataclass(frozen=True)
class View:
    """One image's board detection, named after its file so reports point at the image."""

    name: str
    detection: Detection


@dataclass(frozen=True)
class ViewReport:
    name: str
    rms_px: float | None  # in the last calibration it took part in; None: no board
    used: bool
    reason: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "rms_px": self.rms_px, "used": self.used, "reason": self.reason}


@dataclass(frozen=True)
class Fit:
    """One ``calibrateCameraExtended`` run on a list of views."""

    rms_px: float
    K: np.ndarray
    dist: np.ndarray
    rvecs: tuple[np.ndarray, ...]
    tvecs: tuple[np.ndarray, ...]
    std_intrinsics: np.ndarray
    per_view_rms_px: np.ndarray


def fit(views: Sequence[View], image_size: tuple[int, int], config: CalibrationConfig) -> Fit:
    """A single calibration of ``views`` (no rejection)."""
    obj = [v.detection.object_points.reshape(-1, 1, 3) for v in views]
    img = [v.detection.image_points.reshape(-1, 1, 2) for v in views]
    try:
        rms, K, dist, rvecs, tvecs, std_in, _, per_view = cv2.calibrateCameraExtended(
            obj, img, image_size, np.zeros((3, 3)), config.initial_dist(), flags=config.flags,
            criteria=_CRITERIA,
        )  # fmt: skip
    except cv2.error as exc:
        raise BoardNotFoundError(
            f"calibration failed on {len(views)} views ({exc.err}); the views may be too few "
            "or too similar"
        ) from exc
    return Fit(
        float(rms),
        np.asarray(K, np.float64),
        np.asarray(dist, np.float64).ravel(),
        tuple(np.asarray(r, np.float64).ravel() for r in rvecs),
        tuple(np.asarray(t, np.float64).ravel() for t in tvecs),
        np.asarray(std_in, np.float64).ravel(),
        np.asarray(per_view, np.float64).ravel(),
    )


def reprojection_residuals(
    view: View, K: np.ndarray, dist: np.ndarray, rvec: np.ndarray, tvec: np.ndarray
) -> np.ndarray:
    """Detected minus projected corners (N,2) in px."""
    proj, _ = cv2.projectPoints(view.detection.object_points, rvec, tvec, K, dist)
    return view.detection.image_points.astype(np.float64) - proj.reshape(-1, 2)


def heldout_rms_px(views: Sequence[View], K: np.ndarray, dist: np.ndarray) -> float:
    """RMS on views a calibration never saw: each board pose by PnP, intrinsics held fixed."""
    sq_sum, count = 0.0, 0
    for view in views:
        ok, rvec, tvec = cv2.solvePnP(
            view.detection.object_points, view.detection.image_points, K, dist
        )
        if not ok:
            continue
        rvec, tvec = cv2.solvePnPRefineLM(
            view.detection.object_points, view.detection.image_points, K, dist, rvec, tvec
        )
        res = reprojection_residuals(view, K, dist, rvec, tvec)
        sq_sum += float(np.sum(res**2))
        count += len(res)
    return math.sqrt(sq_sum / count) if count else float("nan")


def coverage_map(
    views: Sequence[View], image_size: tuple[int, int], grid: tuple[int, int]
) -> np.ndarray:
    """Corner counts per cell (rows, cols) of a ``grid`` laid over the image."""
    cols, rows = grid
    counts = np.zeros((rows, cols), np.int64)
    width, height = image_size
    for view in views:
        pts = view.detection.image_points
        cx = np.clip((pts[:, 0] / width * cols).astype(int), 0, cols - 1)
        cy = np.clip((pts[:, 1] / height * rows).astype(int), 0, rows - 1)
        np.add.at(counts, (cy, cx), 1)
    return counts


@dataclass(frozen=True, eq=False)
class IntrinsicsResult:
    """A calibrated camera and the evidence that it is good."""

    camera: CameraModel
    rms_px: float
    views: tuple[ViewReport, ...]
    std: dict[str, float]
    cross_validation: dict[str, float]
    coverage: np.ndarray
    residuals_px: np.ndarray  # (M,2) of the used views, for the scatter plot
    used_views: tuple[View, ...]
    cam_T_boards: tuple[np.ndarray, ...] = field(repr=False)  # noqa: N815 (frame names)
    warnings: tuple[str, ...] = ()

    @property
    def views_used(self) -> int:
        return sum(v.used for v in self.views)

    @property
    def views_rejected(self) -> int:
        return sum(not v.used for v in self.views)

    @property
    def coverage_fraction(self) -> float:
        return float(np.count_nonzero(self.coverage)) / self.coverage.size

    def summary(self) -> dict[str, Any]:
        """JSON-ready: fx, fy, cx, cy, rms_px, ±σ, views, cross-validation, coverage, warnings."""
        out = self.camera.summary()
        out.update(
            rms_px=self.rms_px,
            views_used=self.views_used,
            views_rejected=self.views_rejected,
            sigma=self.std,
            cross_validation=self.cross_validation,
            coverage=self.coverage_fraction,
            rejected=[v.as_dict() for v in self.views if not v.used],
            per_view_rms_px={v.name: v.rms_px for v in self.views if v.used},
            warnings=list(self.warnings),
        )
        return out

    def fs_extra(self, prefix: str = "") -> dict[str, Any]:
        """Quality figures stored beside K and dist in the FileStorage file."""
        std = np.array([self.std.get(n, 0.0) for n in _STD_NAMES[: 4 + self.camera.dist.size]])
        return {
            f"{prefix}rms_px": self.rms_px,
            f"{prefix}views_used": self.views_used,
            f"{prefix}views_rejected": self.views_rejected,
            f"{prefix}std_dev_intrinsics": std.reshape(1, -1),
            f"{prefix}per_view_rms_px": np.array([v.rms_px for v in self.views if v.used]).reshape(
                1, -1
            ),
            f"{prefix}coverage_map": self.coverage.astype(np.float64),
        }


def _pose(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec
    return T


def calibrate_camera(
    views: Sequence[View],
    image_size: tuple[int, int],
    config: CalibrationConfig | None = None,
    name: str = "camera",
    failed: Sequence[str] = (),
) -> IntrinsicsResult:
    """Calibrate one camera from board views, rejecting outlier views iteratively.

    ``failed`` names images in which no board was found; they are listed as rejected views.
    """
    config = config or CalibrationConfig()
    if len(views) < config.min_views:
        raise BoardNotFoundError(
            f"{name}: the board was found in only {len(views)} image(s); at least "
            f"{config.min_views} views are needed"
        )
    kept = list(views)
    reports: dict[str, ViewReport] = {n: ViewReport(n, None, False, "no board") for n in failed}
    while True:
        result = fit(kept, image_size, config)
        errors = result.per_view_rms_px
        worst = int(np.argmax(errors))
        median = float(np.median(np.delete(errors, worst)))
        limit = max(config.reject_factor * median, config.reject_floor_px)
        if not (config.reject_outliers and errors[worst] > limit and len(kept) > config.min_views):
            break
        reason = f"outlier: {errors[worst]:.3f} px > {limit:.3f} px"
        reports[kept[worst].name] = ViewReport(
            kept[worst].name, float(errors[worst]), False, reason
        )
        del kept[worst]
    for view, err in zip(kept, result.per_view_rms_px, strict=True):
        reports[view.name] = ViewReport(view.name, float(err), True)

    camera = CameraModel(K=result.K, dist=result.dist, image_size=image_size, name=name)
    n_params = 4 + result.dist.size
    std = {n: float(s) for n, s in zip(_STD_NAMES[:n_params], result.std_intrinsics, strict=False)}
    residuals = np.concatenate(
        [
            reprojection_residuals(v, result.K, result.dist, r, t)
            for v, r, t in zip(kept, result.rvecs, result.tvecs, strict=True)
        ]
    )
    cross = cross_validate(kept, image_size, config)
    coverage = coverage_map(kept, image_size, config.coverage_grid)
    ordered = tuple(reports[n] for n in sorted(reports))
    res = IntrinsicsResult(
        camera=camera,
        rms_px=result.rms_px,
        views=ordered,
        std=std,
        cross_validation=cross,
        coverage=coverage,
        residuals_px=residuals,
        used_views=tuple(kept),
        cam_T_boards=tuple(_pose(r, t) for r, t in zip(result.rvecs, result.tvecs, strict=True)),
    )
    return _with_warnings(res, config)


def cross_validate(
    views: Sequence[View], image_size: tuple[int, int], config: CalibrationConfig
) -> dict[str, float]:
    """Calibrate the odd and the even views separately and compare.

    Returns the absolute differences of fx, fy, cx, cy (px), fx's relative difference (%) and the
    held-out RMS: each half's intrinsics tested on the other half's views.
    """
    if len(views) < 6:
        return {}
    even, odd = list(views[0::2]), list(views[1::2])
    try:
        fit_even, fit_odd = fit(even, image_size, config), fit(odd, image_size, config)
    except BoardNotFoundError:
        return {}
    diff = np.abs(fit_even.K - fit_odd.K)
    heldout = 0.5 * (
        heldout_rms_px(odd, fit_even.K, fit_even.dist)
        + heldout_rms_px(even, fit_odd.K, fit_odd.dist)
    )
    mean_f = 0.5 * (fit_even.K[0, 0] + fit_odd.K[0, 0])
    return {
        "fx_px": float(diff[0, 0]),
        "fy_px": float(diff[1, 1]),
        "cx_px": float(diff[0, 2]),
        "cy_px": float(diff[1, 2]),
        "fx_pct": float(100.0 * diff[0, 0] / mean_f),
        "heldout_rms_px": float(heldout),
    }


def _with_warnings(res: IntrinsicsResult, config: CalibrationConfig) -> IntrinsicsResult:
    name = res.camera.name
    warnings: list[str] = []
    if res.rms_px > config.warn_rms_px:
        warnings.append(
            f"{name}: RMS {res.rms_px:.3f} px is above {config.warn_rms_px} px: check focus, "
            "motion blur and that the board is flat"
        )
    if res.coverage_fraction < config.warn_coverage:
        warnings.append(
            f"{name}: corners cover only {100 * res.coverage_fraction:.0f}% of the image; "
            "show the board near the edges and corners too"
        )
    if res.views_rejected > res.views_used:
        warnings.append(f"{name}: more views rejected ({res.views_rejected}) than used")
    for key in ("fx", "fy"):
        sigma = res.std.get(key, 0.0)
        value = getattr(res.camera, key)
        if sigma > 0.01 * value:
            warnings.append(f"{name}: σ({key}) = {sigma:.2f} px is above 1% of {key}")
    if res.cross_validation.get("fx_pct", 0.0) > 2.0:
        warnings.append(
            f"{name}: odd/even halves disagree on fx by {res.cross_validation['fx_pct']:.1f}%: "
            "add views with more tilt"
        )
    return dataclasses.replace(res, warnings=tuple(warnings))
