"""Stereo calibration: each camera alone first, then R, T between them on the shared views.

Each camera is calibrated with every view in which it saw the board (more views, better
intrinsics, own outlier rejection). ``cv2.stereoCalibrateExtended`` then fits R, T with the
intrinsics held fixed, on the pairs both cameras kept, and rejects outlier pairs the same way.
Before that, each pair is put into one corner order: common ids for ChArUco, and for a
point-symmetric chessboard the right view is turned by 180° when it runs against the left one.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from calibration.boards import MIN_CHARUCO_CORNERS, BoardSpec, Detection
from calibration.camera import CameraModel
from calibration.errors import BoardNotFoundError
from calibration.intrinsics import (
    CalibrationConfig,
    IntrinsicsResult,
    View,
    ViewReport,
    calibrate_camera,
)
from calibration.triangulate import StereoRig

_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-9)


@dataclass(frozen=True)
class StereoPair:
    """One named image pair and the board in each image (``None``: not found)."""

    name: str
    left: Detection | None
    right: Detection | None


def align_pair(left: Detection, right: Detection, board: BoardSpec) -> tuple[Detection, Detection]:
    """The corners both views share, in the same order in both."""
    if board.point_symmetric:
        d_l = left.image_points[-1] - left.image_points[0]
        d_r = right.image_points[-1] - right.image_points[0]
        if float(np.dot(d_l, d_r)) < 0:  # the two cameras started counting at opposite ends
            right = right.reversed()
    common = np.intersect1d(left.ids, right.ids)
    if len(common) == len(left.ids) == len(right.ids):
        return left, right
    return left.subset(common), right.subset(common)


@dataclass(frozen=True)
class _StereoFit:
    rms_px: float
    R: np.ndarray
    T: np.ndarray
    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    per_pair_rms_px: np.ndarray


def _stereo_fit(
    lefts: Sequence[View],
    rights: Sequence[View],
    left_cam: CameraModel,
    right_cam: CameraModel,
    flags: int,
) -> _StereoFit:
    obj = [v.detection.object_points.reshape(-1, 1, 3) for v in lefts]
    img_l = [v.detection.image_points.reshape(-1, 1, 2) for v in lefts]
    img_r = [v.detection.image_points.reshape(-1, 1, 2) for v in rights]
    try:
        rms, K1, D1, K2, D2, R, T, _, _, _, _, per_view = cv2.stereoCalibrateExtended(
            obj, img_l, img_r, left_cam.K.copy(), left_cam.dist.copy(), right_cam.K.copy(),
            right_cam.dist.copy(), left_cam.image_size, np.eye(3), np.zeros((3, 1)),
            flags=flags, criteria=_CRITERIA,
        )  # fmt: skip
    except cv2.error as exc:
        raise BoardNotFoundError(
            f"stereo calibration failed on {len(lefts)} pairs ({exc.err})"
        ) from exc
    per_view = np.asarray(per_view, np.float64).reshape(-1, 2)
    return _StereoFit(
        float(rms),
        np.asarray(R, np.float64),
        np.asarray(T, np.float64).ravel(),
        np.asarray(K1, np.float64),
        np.asarray(D1, np.float64).ravel(),
        np.asarray(K2, np.float64),
        np.asarray(D2, np.float64).ravel(),
        np.sqrt(np.mean(per_view**2, axis=1)),
    )


@dataclass(frozen=True, eq=False)
class StereoResult:
    left: IntrinsicsResult
    right: IntrinsicsResult
    rig: StereoRig
    rms_px: float
    pairs: tuple[ViewReport, ...]
    epipolar_rms_px: float
    epipolar_max_px: float
    cross_validation: dict[str, float]
    warnings: tuple[str, ...] = ()

    @property
    def views_used(self) -> int:
        return sum(p.used for p in self.pairs)

    @property
    def views_rejected(self) -> int:
        return sum(not p.used for p in self.pairs)

    @property
    def all_warnings(self) -> tuple[str, ...]:
        return self.left.warnings + self.right.warnings + self.warnings

    def summary(self) -> dict[str, Any]:
        """JSON-ready: stereo RMS, pair counts, both cameras, baseline (board units), R, T."""
        return {
            "rms_px": self.rms_px,
            "views_used": self.views_used,
            "views_rejected": self.views_rejected,
            "baseline": self.rig.baseline,
            "R": self.rig.R.tolist(),
            "T": self.rig.T.tolist(),
            "epipolar_rms_px": self.epipolar_rms_px,
            "epipolar_max_px": self.epipolar_max_px,
            "cross_validation": self.cross_validation,
            "rejected": [p.as_dict() for p in self.pairs if not p.used],
            "per_pair_rms_px": {p.name: p.rms_px for p in self.pairs if p.used},
            "left": self.left.summary(),
            "right": self.right.summary(),
            "warnings": list(self.all_warnings),
        }

    def fs_extra(self) -> dict[str, Any]:
        extra: dict[str, Any] = {
            "rms_px": self.rms_px,
            "views_used": self.views_used,
            "views_rejected": self.views_rejected,
            "epipolar_rms_px": self.epipolar_rms_px,
        }
        extra.update(self.left.fs_extra("left_"))
        extra.update(self.right.fs_extra("right_"))
        return extra


def calibrate_stereo(
    pairs: Sequence[StereoPair],
    board: BoardSpec,
    image_size: tuple[int, int],
    config: CalibrationConfig | None = None,
    refine_intrinsics: bool = False,
    names: tuple[str, str] = ("left", "right"),
) -> StereoResult:
    """Calibrate both cameras and the rig from named image pairs.

    ``refine_intrinsics`` lets ``stereoCalibrate`` adjust K and dist too (from the mono result);
    by default they are held fixed, which is more robust with few pairs.
    """
    config = config or CalibrationConfig()
    mono: list[IntrinsicsResult] = []
    for side, name in enumerate(names):
        views = [View(p.name, d) for p in pairs if (d := (p.left, p.right)[side]) is not None]
        failed = [p.name for p in pairs if (p.left, p.right)[side] is None]
        mono.append(calibrate_camera(views, image_size, config, name=name, failed=failed))
    left_res, right_res = mono
    kept_l = {v.name: v for v in left_res.used_views}
    kept_r = {v.name: v for v in right_res.used_views}

    reports: dict[str, ViewReport] = {}
    candidates: list[tuple[View, View]] = []
    for pair in pairs:
        why = _pair_problem(pair, kept_l, kept_r, names)
        if why:
            reports[pair.name] = ViewReport(pair.name, None, False, why)
            continue
        dl, dr = align_pair(kept_l[pair.name].detection, kept_r[pair.name].detection, board)
        if len(dl) < MIN_CHARUCO_CORNERS:
            reports[pair.name] = ViewReport(pair.name, None, False, "too few common corners")
            continue
        candidates.append((View(pair.name, dl), View(pair.name, dr)))
    if len(candidates) < config.min_views:
        raise BoardNotFoundError(
            f"only {len(candidates)} image pairs have the board in both cameras; at least "
            f"{config.min_views} are needed"
        )

    flags = (
        cv2.CALIB_USE_INTRINSIC_GUESS | config.flags
        if refine_intrinsics
        else cv2.CALIB_FIX_INTRINSIC
    )
    while True:
        result = _stereo_fit(
            [c[0] for c in candidates],
            [c[1] for c in candidates],
            left_res.camera,
            right_res.camera,
            flags,
        )
        errors = result.per_pair_rms_px
        worst = int(np.argmax(errors))
        median = float(np.median(np.delete(errors, worst)))
        limit = max(config.reject_factor * median, config.reject_floor_px)
        if not (
            config.reject_outliers and errors[worst] > limit and len(candidates) > config.min_views
        ):
            break
        name = candidates[worst][0].name
        reports[name] = ViewReport(
            name, float(errors[worst]), False, f"stereo outlier: {errors[worst]:.3f} px > "
            f"{limit:.3f} px",
        )  # fmt: skip
        del candidates[worst]
    for (view, _), err in zip(candidates, result.per_pair_rms_px, strict=True):
        reports[view.name] = ViewReport(view.name, float(err), True)

    left_cam, right_cam = left_res.camera, right_res.camera
    if refine_intrinsics:
        left_cam = dataclasses.replace(left_cam, K=result.K1, dist=result.D1)
        right_cam = dataclasses.replace(right_cam, K=result.K2, dist=result.D2)
    rig = StereoRig(left_cam, right_cam, result.R, result.T)
    epi = np.concatenate(
        [rig.epipolar_errors_px(lv.detection.image_points, rv.detection.image_points)
         for lv, rv in candidates]
    )  # fmt: skip
    cross = _cross_validate(candidates, left_cam, right_cam, rig.baseline)
    res = StereoResult(
        left=left_res,
        right=right_res,
        rig=rig,
        rms_px=result.rms_px,
        pairs=tuple(reports[n] for n in sorted(reports)),
        epipolar_rms_px=float(np.sqrt(np.mean(epi**2))),
        epipolar_max_px=float(np.max(epi)),
        cross_validation=cross,
    )
    return dataclasses.replace(res, warnings=_warnings(res, config))


def _pair_problem(
    pair: StereoPair, kept_l: dict[str, View], kept_r: dict[str, View], names: tuple[str, str]
) -> str:
    for det, kept, side in ((pair.left, kept_l, names[0]), (pair.right, kept_r, names[1])):
        if det is None:
            return f"no board in the {side} image"
        if pair.name not in kept:
            return f"{side} view rejected"
    return ""


def _cross_validate(
    candidates: Sequence[tuple[View, View]],
    left_cam: CameraModel,
    right_cam: CameraModel,
    baseline: float,
) -> dict[str, float]:
    """Baselines from the even and from the odd pairs alone, and how far apart they are."""
    if len(candidates) < 6:
        return {}
    halves = [list(candidates[0::2]), list(candidates[1::2])]
    baselines = []
    for half in halves:
        fit = _stereo_fit(
            [c[0] for c in half], [c[1] for c in half], left_cam, right_cam,
            cv2.CALIB_FIX_INTRINSIC,
        )  # fmt: skip
        baselines.append(float(np.linalg.norm(fit.T)))
    return {
        "baseline_even": baselines[0],
        "baseline_odd": baselines[1],
        "baseline_pct": 100.0 * abs(baselines[0] - baselines[1]) / baseline,
    }


def _warnings(res: StereoResult, config: CalibrationConfig) -> tuple[str, ...]:
    out: list[str] = []
    if res.rms_px > config.warn_rms_px:
        out.append(f"stereo RMS {res.rms_px:.3f} px is above {config.warn_rms_px} px")
    if res.epipolar_rms_px > config.warn_rms_px:
        out.append(
            f"epipolar RMS {res.epipolar_rms_px:.3f} px is above {config.warn_rms_px} px: the "
            "cameras may have moved relative to each other or be out of sync"
        )
    pct = res.cross_validation.get("baseline_pct", 0.0)
    if pct > 1.0 and not math.isnan(pct):
        out.append(f"odd/even pairs disagree on the baseline by {pct:.1f}%")
    return tuple(out)
