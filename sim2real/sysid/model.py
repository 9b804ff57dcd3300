"""The servo model sysid fits: the same physics the emulator and the env's actuation layer use.

Per actuator: the command takes effect ``latency_s`` after it was sent; the horn moves towards
``target + droop`` with a first-order lag ``time_constant_s``, no faster than
``max_speed_rad_s``, and not at all while the error is inside ``deadband_rad``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numba
import numpy as np

from sim2real.errors import ConfigError

SIM_DT_S = 0.001  # integration step of the fit's simulation


@dataclass(frozen=True)
class ServoFit:
    time_constant_s: float
    max_speed_rad_s: float
    deadband_rad: float
    latency_s: float
    droop_rad: float = 0.0  # sag of the pitch joints (negative: down)

    def __post_init__(self) -> None:
        for key, value in asdict(self).items():
            if not math.isfinite(value):
                raise ConfigError(f"servo fit {key} must be finite, got {value}")
        if self.time_constant_s <= 0 or self.max_speed_rad_s <= 0:
            raise ConfigError(
                f"time_constant_s ({self.time_constant_s}) and max_speed_rad_s "
                f"({self.max_speed_rad_s}) must be > 0"
            )


@numba.njit(cache=False)
def _integrate(
    idx: np.ndarray,
    u: np.ndarray,
    x0: np.ndarray,
    offset: np.ndarray,
    alpha: float,
    vmax_dt: float,
    deadband: float,
) -> np.ndarray:  # pragma: no cover - compiled
    n_t, n = len(idx), len(x0)
    out = np.empty((n_t, n))
    x = x0.copy()
    for i in range(n_t):
        k = idx[i]
        if k >= 0:
            for j in range(n):
                err = u[k, j] + offset[j] - x[j]
                if abs(err) > deadband:
                    move = err * alpha
                    if move > vmax_dt:
                        move = vmax_dt
                    elif move < -vmax_dt:
                        move = -vmax_dt
                    x[j] += move
        out[i] = x
    return out


def simulate(
    fit: ServoFit,
    t_cmd_s: np.ndarray,
    u_rad: np.ndarray,
    t_read_s: np.ndarray,
    x0_rad: np.ndarray,
    droop_mask: np.ndarray,
) -> np.ndarray:
    """Positions (len(t_read), n) at the read times, for commands u (k, n) sent at t_cmd (k,)."""
    t0 = min(t_cmd_s[0], t_read_s[0])
    t_end = max(t_cmd_s[-1], t_read_s[-1]) + SIM_DT_S
    grid = np.arange(t0, t_end, SIM_DT_S)
    # Which command is in force at each grid time (after the latency): -1 = none yet.
    idx = np.searchsorted(t_cmd_s + fit.latency_s, grid, side="right") - 1
    out = _integrate(
        idx.astype(np.int64),
        np.ascontiguousarray(u_rad, dtype=np.float64),
        np.asarray(x0_rad, dtype=np.float64),
        fit.droop_rad * np.asarray(droop_mask, dtype=np.float64),
        1.0 - math.exp(-SIM_DT_S / fit.time_constant_s),
        fit.max_speed_rad_s * SIM_DT_S,
        fit.deadband_rad,
    )
    read_idx = np.clip(np.round((t_read_s - t0) / SIM_DT_S).astype(int), 0, len(grid) - 1)
    return out[read_idx]
