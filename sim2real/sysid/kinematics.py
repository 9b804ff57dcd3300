"""Kinematic calibration from the cameras: joint zero offsets and link lengths by least squares.

The wrist marker is seen by both cameras in every period, so each period with a detection is a
3-D point the arm's geometry must explain. The model is the spec's forward kinematics with
unknown ``base_height_m``, ``upper_arm_m``, ``forearm_m`` and joint offsets (``hardware.plant``'s
convention, physical = reading + offset), evaluated at the servo readings::

    marker = Rz(s0 (q0 + d0)) [r_w + mx, my, 0] + [0, 0, z_w + mz]
    r_w = l1 sin a1 + l2 cos a12,  z_w = h + l1 cos a1 - l2 sin a12
    a1 = s1 (q1 + d1),  a12 = a1 + s2 (q2 + d2)

(mx, my, mz) is the centre of the plate's printed face on the level wrist
(``sim2real.model.EE_MARKER_POS_M`` plus half the plate's thickness along its normal);
the tool offsets are not observable from a wrist marker and stay the spec's. A base-yaw offset
also absorbs a yaw error of the camera registration: both turn the arm about the base z axis.

Uncertainty: the Gauss-Newton covariance ``s^2 (J^T J)^-1`` at the solution, with ``s^2`` the
residual variance per coordinate, after one pass that drops gross outliers (a marker decoded at
the wrong corner). It is honest for independent pixel noise; a timing skew between readings and
frames is a bias it cannot see, so excite slowly or use logs stamped at the frame time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from hardware.plant import Plant
from hardware.spec import ArmSpec
from sim2real import model as names
from sim2real.errors import ConfigError
from sim2real.model import RigSpec

PARAM_NAMES: tuple[str, ...] = (
    "base_yaw_offset_rad",
    "shoulder_offset_rad",
    "elbow_offset_rad",
    "base_height_m",
    "upper_arm_m",
    "forearm_m",
)
MIN_OBSERVATIONS = 20
# sim2real.model draws the wrist plate 1.6 mm thick: the printed face the cameras triangulate is
# half of that out along the plate's normal, which the forward tilt turns towards +x and +z.
_PLATE_HALF_THICKNESS_M = 0.0008


def marker_face_p_wrist_m() -> np.ndarray:
    """Centre of the wrist marker's printed face in the level wrist frame (3,)."""
    tilt = names.EE_MARKER_TILT_RAD
    normal = np.array([math.sin(tilt), 0.0, math.cos(tilt)])
    return np.asarray(names.EE_MARKER_POS_M, dtype=float) + _PLATE_HALF_THICKNESS_M * normal


_OUTLIER_SIGMAS = 5.0


@dataclass(frozen=True)
class MarkerObservations:
    """Servo readings and the wrist marker (plate centre) seen at the same instant."""

    joints_rad: np.ndarray  # (k, n_joints) readings
    marker_m: np.ndarray  # (k, 3) base frame
    source: str = "observations"

    def __post_init__(self) -> None:
        q, p = np.asarray(self.joints_rad, float), np.asarray(self.marker_m, float)
        if q.ndim != 2 or p.shape != (len(q), 3):
            raise ConfigError(
                f"{self.source}: joints_rad {q.shape} and marker_m {p.shape} must be (k, n), (k, 3)"
            )
        keep = np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(p), axis=1)
        if keep.sum() < MIN_OBSERVATIONS:
            raise ConfigError(
                f"{self.source}: {int(keep.sum())} periods with a wrist-marker observation; "
                f"kinematic calibration needs >= {MIN_OBSERVATIONS} (are both cameras on and the "
                "wrist marker in view?)"
            )
        object.__setattr__(self, "joints_rad", q[keep])
        object.__setattr__(self, "marker_m", p[keep])


def marker_p_tool_m(spec: ArmSpec) -> np.ndarray:
    """Plate centre -> tool, in the level wrist frame (what the deploy perception adds, from
    the plate's geometric centre: ``MarkerLayout.for_spec``)."""
    mx, my, mz = names.EE_MARKER_POS_M
    L = spec.links
    return np.array([L.tool_forward_m - mx, -my, -L.tool_down_m - mz])


def load_marker_log(path: str | Path, spec: ArmSpec) -> MarkerObservations:
    """A deploy-style npz log → observations. Takes ``ee_marker_m`` (raw marker face centre,
    NaN when unseen) when the log has it; else ``ee_est_m`` (the deploy loop's tool estimate:
    plate + the spec's plate-to-tool offset turned by the yaw reading) turned back into the
    plate, in the periods ``ee_seen`` marks (the others hold forward kinematics, not a view).
    The raw marker is better: ``ee_est_m`` is Kalman-filtered, so it lags a moving wrist.

    A log with ``t_s`` and ``marker_t_s`` (adapt's excitation: when each reading and each view
    was taken) pairs each marker with the readings interpolated to its instant, not with the
    period's reading: the sweep moves a joint up to 0.5 rad/s, so the tens of ms between a
    reading and a frame would be fitted as joint offsets. A marker outside the readings' span
    is dropped (NaN)."""
    p = Path(path)
    try:
        data = dict(np.load(p))
    except FileNotFoundError:
        raise ConfigError(f"log {str(p)!r} does not exist") from None
    except (OSError, ValueError) as exc:
        raise ConfigError(f"log {str(p)!r} is not a readable npz file: {exc}") from None
    if "joints_rad" not in data:
        raise ConfigError(f"log {str(p)!r} has no 'joints_rad': not a deploy or sysid log")
    q = np.asarray(data["joints_rad"], dtype=float)[:, : spec.n_joints]
    if "ee_marker_m" in data:
        marker = np.asarray(data["ee_marker_m"], dtype=float)
    elif "ee_est_m" in data and "ee_seen" in data:
        est = np.where(np.asarray(data["ee_seen"], dtype=bool)[:, None], data["ee_est_m"], np.nan)
        yaw = spec.joints[0].sign * q[:, 0]
        dx, dy, dz = marker_p_tool_m(spec)
        c, s = np.cos(yaw), np.sin(yaw)
        marker = est - np.stack([c * dx - s * dy, s * dx + c * dy, np.full_like(c, dz)], axis=1)
    elif "ee_est_m" in data:
        raise ConfigError(
            f"log {str(p)!r} has 'ee_est_m' but no 'ee_seen': its periods without a marker hold "
            "forward kinematics of the spec, which would pull the fit back to the spec; log "
            "'ee_marker_m' (raw marker, NaN when unseen) or 'ee_seen' beside it"
        )
    else:
        raise ConfigError(
            f"log {str(p)!r} has no wrist-marker observations ('ee_marker_m', or 'ee_est_m' with "
            "'ee_seen'): record it with both cameras on (sim2real deploy --log)"
        )
    if len(marker) != len(q):
        raise ConfigError(f"log {str(p)!r}: {len(marker)} marker rows but {len(q)} joint readings")
    if "marker_t_s" in data and "t_s" in data:
        q, marker = readings_at(
            np.asarray(data["t_s"], dtype=float), q, np.asarray(data["marker_t_s"], dtype=float),
            marker, str(p),
        )  # fmt: skip
    return MarkerObservations(q, marker, source=str(p))


def readings_at(
    t_s: np.ndarray, q_rad: np.ndarray, marker_t_s: np.ndarray, marker_m: np.ndarray, name: str
) -> tuple[np.ndarray, np.ndarray]:
    """The readings ``q_rad`` (taken at ``t_s``) interpolated to each marker's instant, and the
    markers with those outside the readings' span set to NaN (nothing to interpolate from)."""
    if not (len(t_s) == len(marker_t_s) == len(q_rad)):
        raise ConfigError(
            f"log {name!r}: {len(t_s)} reading times and {len(marker_t_s)} marker times for "
            f"{len(q_rad)} readings"
        )
    if len(t_s) == 0:
        return q_rad, marker_m
    if not np.all(np.diff(t_s) > 0):
        raise ConfigError(f"log {name!r}: its reading times 't_s' do not increase")
    at = np.stack([np.interp(marker_t_s, t_s, q_rad[:, j]) for j in range(q_rad.shape[1])], 1)
    outside = (marker_t_s < t_s[0]) | (marker_t_s > t_s[-1]) | ~np.isfinite(marker_t_s)
    return at, np.where(outside[:, None], np.nan, marker_m)


def predict_marker_m(theta: np.ndarray, q_rad: np.ndarray, spec: ArmSpec) -> np.ndarray:
    """Marker positions (k, 3) for parameters ``theta`` (PARAM_NAMES order) at readings (k, n)."""
    d0, d1, d2, h, l1, l2 = theta
    s0, s1, s2 = (j.sign for j in spec.joints)
    mx, my, mz = marker_face_p_wrist_m()
    yaw = s0 * (q_rad[:, 0] + d0)
    a1 = s1 * (q_rad[:, 1] + d1)
    a12 = a1 + s2 * (q_rad[:, 2] + d2)
    r = l1 * np.sin(a1) + l2 * np.cos(a12) + mx
    z = h + l1 * np.cos(a1) - l2 * np.sin(a12) + mz
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * r - s * my, s * r + c * my, z], axis=1)


@dataclass(frozen=True)
class KinematicFit:
    """Fitted values, their 1-sigma uncertainty and the fit quality."""

    values: np.ndarray  # (6,) PARAM_NAMES order
    std: np.ndarray  # (6,)
    covariance: np.ndarray  # (6, 6)
    rms_m: float  # residual RMS distance over the kept observations
    n_used: int
    n_rejected: int

    @property
    def joint_offset_rad(self) -> np.ndarray:
        return self.values[:3].copy()

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            name: round(float(v), 6) for name, v in zip(PARAM_NAMES, self.values, strict=True)
        }
        out.update(
            {
                f"{name}_std": round(float(s), 7)
                for name, s in zip(PARAM_NAMES, self.std, strict=True)
            }
        )
        out.update(rms_m=round(self.rms_m, 6), n_used=self.n_used, n_rejected=self.n_rejected)
        return out

    def fitted_spec(self, spec: ArmSpec) -> ArmSpec:
        """``spec`` with the fitted link lengths (rounded to 0.01 mm)."""
        _, _, _, h, l1, l2 = (round(float(v), 5) for v in self.values)
        return replace(
            spec, links=replace(spec.links, base_height_m=h, upper_arm_m=l1, forearm_m=l2)
        )

    def joint_offsets(self, spec: ArmSpec) -> tuple[tuple[str, float], ...]:
        return tuple(
            (j.name, round(float(d), 5)) for j, d in zip(spec.joints, self.values[:3], strict=True)
        )


def _solve(obs_q: np.ndarray, obs_p: np.ndarray, spec: ArmSpec, x0: np.ndarray) -> Any:
    def residuals(theta: np.ndarray) -> np.ndarray:
        return (predict_marker_m(theta, obs_q, spec) - obs_p).ravel()

    return least_squares(residuals, x0, method="lm", x_scale="jac")


def fit_kinematics(obs: MarkerObservations, spec: ArmSpec) -> KinematicFit:
    """Least squares from the spec's geometry (offsets 0); one outlier pass; covariance."""
    L = spec.links
    x0 = np.array([0.0, 0.0, 0.0, L.base_height_m, L.upper_arm_m, L.forearm_m])
    q, p = obs.joints_rad, obs.marker_m
    sol = _solve(q, p, spec, x0)
    dist = np.linalg.norm(sol.fun.reshape(-1, 3), axis=1)
    sigma = float(np.median(dist)) / 1.538  # the median of a 3-D normal's distance is 1.538 sigma
    keep = dist <= max(_OUTLIER_SIGMAS * sigma, 1e-4)
    if keep.sum() < MIN_OBSERVATIONS:
        raise ConfigError(
            f"{obs.source}: only {int(keep.sum())} consistent marker observations; "
            f"need >= {MIN_OBSERVATIONS}"
        )
    if not keep.all():
        sol = _solve(q[keep], p[keep], spec, sol.x)
    J = sol.jac
    n_res, n_par = J.shape
    jtj = J.T @ J
    cond = float(np.linalg.cond(jtj))
    if not math.isfinite(cond) or cond > 1e14:
        raise ConfigError(
            f"{obs.source}: the excitation does not separate the joint offsets and link lengths "
            f"(J^T J condition {cond:.2e}): move every joint over a wide range"
        )
    s2 = float(sol.fun @ sol.fun) / max(n_res - n_par, 1)
    cov = s2 * np.linalg.inv(jtj)
    rms = float(np.sqrt(np.mean(np.sum(sol.fun.reshape(-1, 3) ** 2, axis=1))))
    return KinematicFit(
        values=np.asarray(sol.x, dtype=float),
        std=np.sqrt(np.diag(cov)),
        covariance=cov,
        rms_m=rms,
        n_used=int(keep.sum()),
        n_rejected=int((~keep).sum()),
    )


def excitation_rad(spec: ArmSpec, duration_s: float, rate_hz: float) -> np.ndarray:
    """Readings (k, n_joints) of a slow Lissajous sweep that moves every joint over a wide range
    with incommensurate periods (so offsets and lengths separate), the wrist kept above the
    table and in front of the cameras, 0.15 rad inside every limit."""
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    lo, hi = spec.lower_rad + 0.15, spec.upper_rad - 0.15
    # yaw within +-0.7 rad keeps the forward-tilted plate readable from the rig in front
    yaw_half = min(0.7, 0.5 * (hi[0] - lo[0]))
    centre = 0.5 * (lo + hi)
    q = np.empty((len(t), spec.n_joints))
    q[:, 0] = centre[0] + yaw_half * np.sin(2 * np.pi * t / 23.0)
    # pitch joints over 60 % of their span, the shoulder leaning back a little: the tool stays
    # >= 1 cm above the table by the spec (and by every shipped plant)
    q[:, 1] = centre[1] - 0.1 + 0.3 * (hi[1] - lo[1]) * np.sin(2 * np.pi * t / 11.0 + 0.4)
    q[:, 2] = centre[2] + 0.3 * (hi[2] - lo[2]) * np.sin(2 * np.pi * t / 7.0 + 1.1)
    return q


def observe_rendered(
    plant: Plant,
    readings_rad: np.ndarray,
    rng: np.random.Generator,
    rig: RigSpec | None = None,
) -> tuple[MarkerObservations, np.ndarray]:
    """The mock cameras' view of an excitation: the PLANT's arm (its links) rendered at the
    physical angles ``readings + offsets``, the wrist marker detected and triangulated in both
    frames (``calibration.perception.StereoMarkerTracker``, raw, unfiltered), paired with the
    readings the servos report (plant noise, quantised at the plant's resolution).

    Returns the observations (undetected periods dropped) and the detection rate per period.
    Readings and frames are of the same instant: the timing skew of a live loop is not modelled.
    """
    from calibration.perception import StereoMarkerTracker
    from sim2real.deploy.virtual_cameras import VirtualStereoCameras, stereo_rig_of

    spec = plant.spec
    q_true = np.asarray(readings_rad, dtype=float)
    cams = VirtualStereoCameras(spec, rig)
    stereo, base_T_left = stereo_rig_of(cams.rig)
    tracker = StereoMarkerTracker(
        stereo,
        base_T_cam=base_T_left,
        marker_id=names.EE_MARKER_ID,
        dictionary=names.MARKER_DICTIONARY,
        marker_length_m=names.EE_MARKER_SIZE_M,
    )
    grip = [spec.gripper.open_rad] if spec.gripper is not None else []
    offsets = plant.offsets_rad()[: spec.n_joints]
    hidden_target = np.array([0.0, 0.6, -0.3])  # under the table, out of every view
    markers = np.full((len(q_true), 3), np.nan)
    try:
        for i, q in enumerate(q_true):
            cams.pose(np.concatenate([q + offsets, grip]), hidden_target)
            frames = cams.read()
            meas = tracker.measure(frames.left_bgr, frames.right_bgr)
            if meas is not None:
                markers[i] = meas.position_m
    finally:
        cams.close()
    reported = (
        q_true + rng.normal(0.0, plant.noise_rad, q_true.shape) if plant.noise_rad else q_true
    )
    res = spec.servo.resolution_rad
    if res > 0:
        reported = np.round(reported / res) * res
    seen = np.all(np.isfinite(markers), axis=1)
    return MarkerObservations(reported, markers, source="rendered excitation"), seen


def load_marker_logs(paths: list[Path], spec: ArmSpec) -> MarkerObservations:
    """Several logs as one set of observations (each must have markers)."""
    parts = [load_marker_log(p, spec) for p in paths]
    return MarkerObservations(
        np.concatenate([o.joints_rad for o in parts]),
        np.concatenate([o.marker_m for o in parts]),
        source=", ".join(str(p) for p in paths),
    )


def estimated_plant(spec: ArmSpec, fit: KinematicFit, droop_rad: float = 0.0) -> Plant:
    """What calibration found, as a plant file (``--plant`` takes it): ``spec`` (already holding
    any servo fit) with the fitted links, and the joint offsets."""
    return Plant(
        fit.fitted_spec(spec),
        joint_offset_rad=fit.joint_offsets(spec),
        droop_rad=max(0.0, droop_rad),
        source="sysid --kinematics",
    )


def describe(fit: KinematicFit) -> str:
    """One line per parameter with its 1-sigma uncertainty, for file headers."""
    lines = []
    for name, v, s in zip(PARAM_NAMES, fit.values, fit.std, strict=True):
        if name.endswith("_m"):
            lines.append(f"{name} = {v * 1000:.2f} +- {s * 1000:.2f} mm")
        else:
            lines.append(f"{name} = {v:+.4f} +- {s:.4f} rad")
    lines.append(
        f"from {fit.n_used} marker observations ({fit.n_rejected} outliers dropped), "
        f"residual RMS {fit.rms_m * 1000:.2f} mm"
    )
    return "\n".join(lines)
