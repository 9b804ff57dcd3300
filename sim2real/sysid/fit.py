"""Fit ``ServoFit`` to logs by simulating the servo model and minimising the reading error."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from hardware.spec import ArmSpec
from sim2real.errors import ConfigError
from sim2real.sysid.model import ServoFit, simulate

LOG_KEYS = ("t_s", "joints_rad", "t_cmd_s", "sent_rad")


@dataclass(frozen=True)
class Trajectory:
    t_read_s: np.ndarray  # (k,)
    readings_rad: np.ndarray  # (k, n_joints)
    t_cmd_s: np.ndarray  # (m,)
    commands_rad: np.ndarray  # (m, n_joints)


def load_log(path: str | Path, n_joints: int) -> Trajectory:
    """A deploy or sysid log (npz); errors name the file and what is missing."""
    p = Path(path)
    try:
        data = np.load(p)
    except FileNotFoundError:
        raise ConfigError(f"log {str(p)!r} does not exist") from None
    except (OSError, ValueError) as exc:
        raise ConfigError(f"log {str(p)!r} is not a readable npz file: {exc}") from None
    missing = [k for k in LOG_KEYS if k not in data]
    if missing:
        raise ConfigError(f"log {str(p)!r} lacks {missing}; expected keys {list(LOG_KEYS)}")
    y = np.asarray(data["joints_rad"], dtype=float)[:, :n_joints]
    u = np.asarray(data["sent_rad"], dtype=float)[:, :n_joints]
    ok = np.all(np.isfinite(u), axis=1)  # a dry run logs NaN commands: nothing was sent
    if ok.sum() < 20:
        raise ConfigError(f"log {str(p)!r} has only {int(ok.sum())} commanded periods; need >= 20")
    return Trajectory(data["t_s"], y, data["t_cmd_s"][ok], u[ok])


def _residuals(fit: ServoFit, trajs: Sequence[Trajectory], mask: np.ndarray) -> np.ndarray:
    return np.concatenate(
        [
            (
                simulate(fit, tr.t_cmd_s, tr.commands_rad, tr.t_read_s, tr.readings_rad[0], mask)
                - tr.readings_rad
            ).ravel()
            for tr in trajs
        ]
    )


def _residual_rms(fit: ServoFit, trajs: Sequence[Trajectory], mask: np.ndarray) -> float:
    r = _residuals(fit, trajs, mask)
    return math.sqrt(float(np.mean(r * r)))


HUBER_RAD = 0.01


def _robust_cost(fit: ServoFit, trajs: Sequence[Trajectory], mask: np.ndarray) -> float:
    """Huber loss: a period the host was descheduled in (its time stamp off by tens of ms)
    costs linearly, so a few such periods cannot drag the lag or the latency."""
    a = np.abs(_residuals(fit, trajs, mask))
    quad = np.minimum(a, HUBER_RAD)
    return float(np.mean(0.5 * quad * quad + HUBER_RAD * (a - quad)))


def _initial_guess(trajs: Sequence[Trajectory]) -> ServoFit:
    speeds = np.concatenate(
        [np.abs(np.diff(tr.readings_rad, axis=0)) / np.diff(tr.t_read_s)[:, None] for tr in trajs]
    )
    return ServoFit(
        time_constant_s=0.05,
        max_speed_rad_s=float(np.percentile(speeds, 99.5)),
        deadband_rad=0.005,
        latency_s=0.01,
        droop_rad=0.0,
    )


LATENCY_SCAN_S = np.arange(0.0, 0.3001, 0.005)  # candidate dead times for the starting point


def _latency_scan(objective: Callable[[ServoFit], float], start: ServoFit) -> ServoFit:
    """Start from the best latency on a coarse grid (other parameters at their guess): a
    simplex started 100 ms away from the dead time can settle in a local minimum that trades
    the missing delay for lag and dead band."""
    costs = [objective(replace(start, latency_s=float(lat))) for lat in LATENCY_SCAN_S]
    return replace(start, latency_s=float(LATENCY_SCAN_S[int(np.argmin(costs))]))


def _nelder_mead(
    objective: Callable[[ServoFit], float], start: ServoFit, fit_droop: bool, max_iter: int
) -> ServoFit:
    def unpack(v: np.ndarray) -> ServoFit:
        return ServoFit(
            time_constant_s=math.exp(v[0]),
            max_speed_rad_s=math.exp(v[1]),
            deadband_rad=abs(v[2]),
            latency_s=abs(v[3]),
            droop_rad=v[4] if fit_droop else start.droop_rad,
        )

    v0 = np.array(
        [
            math.log(start.time_constant_s),
            math.log(start.max_speed_rad_s),
            start.deadband_rad,
            start.latency_s,
            start.droop_rad,
        ]
    )
    n = 5 if fit_droop else 4
    steps = np.array([0.3, 0.2, 0.003, 0.005, 0.005])[:n]
    res = minimize(
        lambda v: objective(unpack(np.append(v, v0[n:]))),
        v0[:n],
        method="Nelder-Mead",
        options={
            "maxiter": max_iter,
            "xatol": 1e-5,
            "fatol": 1e-9,
            "initial_simplex": np.vstack([v0[:n], v0[:n] + np.diag(steps)]),
        },
    )
    return unpack(np.append(res.x, v0[n:]))


def fit_servo(
    trajs: Sequence[Trajectory], spec: ArmSpec, fit_droop: bool = False, max_iter: int = 400
) -> tuple[ServoFit, float]:
    """(fit, RMS reading error in rad).

    Nelder–Mead, because the dead band and the speed limit make the error surface kinked, in
    stages so that droop cannot trade off against the lag: the latency on a coarse grid, the
    dynamics from there, then the droop alone (a 1-D bounded search), then everything together.
    The simulation applies the latency to the sub-step, so the cost is continuous in it."""
    mask = np.array([1.0 if j.axis.lstrip("-") == "y" else 0.0 for j in spec.joints])

    def objective(f: ServoFit) -> float:
        return _robust_cost(f, trajs, mask)

    best = _nelder_mead(objective, _latency_scan(objective, _initial_guess(trajs)), False, max_iter)
    if fit_droop:
        droop = minimize_scalar(
            lambda d: objective(replace(best, droop_rad=d)), bounds=(-0.2, 0.2), method="bounded"
        ).x
        best = _nelder_mead(objective, replace(best, droop_rad=float(droop)), True, max_iter)
    return best, _residual_rms(best, trajs, mask)
