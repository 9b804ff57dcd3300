"""The servo model sysid fits: ``hardware.servo_model.ServoBank``, the one servo model, in
continuous time (the emulator runs the same). ``simulate`` integrates it with a compiled kernel
because a fit calls it thousands of times; ``simulate(..., engine="model")`` runs the model itself,
and a test holds the two equal.

Per actuator: the command takes effect ``latency_s`` after it was sent; the horn moves towards
``target + droop`` with a first-order lag ``time_constant_s``, no faster than
``max_speed_rad_s``, and not at all while the error is inside ``deadband_rad``.

What ``latency_s`` means: the command-to-motion dead time *as the host log sees it*, i.e. from
the host's stamp before sending a command (``t_cmd_s``) to the servo starting to act on it, minus
the delay between the host's stamp before a read (``t_s``) and the device sampling the position.
It contains the servo's own dead time (PWM frame, firmware) plus the write's transport (USB
adapter, wire), less the read request's transport; the reply's return trip does not count (the
device samples when the request arrives). Where writes and read requests take the same path the
transports cancel and it is the servo's own dead time. Either way it is the delay, beyond the
host's own stamps, between a position being sampled and a command computed from it acting, which
is what the DR's ``actuation.latency_steps`` stands for.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numba
import numpy as np

from hardware.servo_model import ServoBank, ServoParams
from sim2real.errors import ConfigError, UnknownNameError

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
def _servo_step(
    x: np.ndarray,
    target: np.ndarray,
    offset: np.ndarray,
    h: float,
    tau: float,
    vmax: float,
    deadband: float,
) -> None:  # pragma: no cover - compiled
    """One exact first-order step of length h, speed-limited, with the dead band, in place."""
    alpha = 1.0 - math.exp(-h / tau)
    vmax_h = vmax * h
    for j in range(len(x)):
        err = target[j] + offset[j] - x[j]
        if abs(err) > deadband:
            move = err * alpha
            if move > vmax_h:
                move = vmax_h
            elif move < -vmax_h:
                move = -vmax_h
            x[j] += move


@numba.njit(cache=False)
def _integrate(
    idx: np.ndarray,
    after: np.ndarray,
    u: np.ndarray,
    x0: np.ndarray,
    offset: np.ndarray,
    dt: float,
    tau: float,
    vmax: float,
    deadband: float,
) -> np.ndarray:  # pragma: no cover - compiled
    """Step i covers (t_i - dt, t_i]; command idx[i] is in force for the last ``after[i]``
    fraction of it and the one before for the rest (nothing moves before the first command).
    Splitting the step makes the result continuous in the latency instead of jumping by whole
    steps, so Nelder–Mead sees a slope."""
    n_t, n = len(idx), len(x0)
    out = np.empty((n_t, n))
    x = x0.copy()
    for i in range(n_t):
        k = idx[i]
        if k >= 0:
            w = after[i]
            if w >= 1.0:
                _servo_step(x, u[k], offset, dt, tau, vmax, deadband)
            else:
                if k >= 1:
                    _servo_step(x, u[k - 1], offset, (1.0 - w) * dt, tau, vmax, deadband)
                if w > 0.0:
                    _servo_step(x, u[k], offset, w * dt, tau, vmax, deadband)
        out[i] = x
    return out


def _compiled(
    fit: ServoFit, grid: np.ndarray, t_cmd_s: np.ndarray, u: np.ndarray, x0: np.ndarray,
    offset: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """The numba kernel (a fit calls it thousands of times)."""
    switch_s = t_cmd_s + fit.latency_s
    # Which command is in force at the end of each step (after the latency): -1 = none yet,
    # and for how much of the step it has been.
    idx = np.searchsorted(switch_s, grid, side="right") - 1
    after = np.ones(len(grid))
    has = idx >= 0
    after[has] = np.clip((grid[has] - switch_s[idx[has]]) / SIM_DT_S, 0.0, 1.0)
    return _integrate(
        idx.astype(np.int64), after, u, x0, offset, SIM_DT_S, fit.time_constant_s,
        fit.max_speed_rad_s, fit.deadband_rad,
    )  # fmt: skip


def _model(
    fit: ServoFit, grid: np.ndarray, t_cmd_s: np.ndarray, u: np.ndarray, x0: np.ndarray,
    offset: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """The one servo model, ``hardware.servo_model.ServoBank``, step by step in numpy: the
    definition the compiled kernel must equal (slow: for tests). Nothing moves before the first
    command takes effect."""
    n = len(x0)
    params = ServoParams(
        max_speed_rad_s=np.full(n, fit.max_speed_rad_s),
        time_constant_s=fit.time_constant_s,
        deadband_rad=fit.deadband_rad,
        resolution_rad=0.0,
        droop_rad=offset,
        noise_rad=0.0,  # the latency is applied below, when the commands are queued
    )
    bank = ServoBank(params, x0)
    for t_s, target in zip(t_cmd_s, u, strict=True):
        bank.delay.push(float(t_s) + fit.latency_s, target)
    powered = np.ones(n, dtype=bool)
    out = np.empty((len(grid), n))
    for i, t_s in enumerate(grid):
        bank.run(float(t_s) - SIM_DT_S, float(t_s), powered)
        out[i] = bank.pos
    return out


ENGINES = {"compiled": _compiled, "model": _model}


def simulate(
    fit: ServoFit,
    t_cmd_s: np.ndarray,
    u_rad: np.ndarray,
    t_read_s: np.ndarray,
    x0_rad: np.ndarray,
    droop_mask: np.ndarray,
    engine: str = "compiled",
) -> np.ndarray:
    """Positions (len(t_read), n) at the read times, for commands u (k, n) sent at t_cmd (k,).

    Command k acts from ``t_cmd_s[k] + latency_s`` on, to the sub-step; readings are linearly
    interpolated between integration steps. ``engine``: ``compiled`` (numba) or ``model`` (the
    numpy servo model it is tested against)."""
    if engine not in ENGINES:
        raise UnknownNameError("sysid engine", engine, ENGINES)
    t_cmd = np.asarray(t_cmd_s, dtype=np.float64)
    t0 = min(t_cmd[0], t_read_s[0])
    grid = np.arange(t0, max(t_cmd[-1], t_read_s[-1]) + 2 * SIM_DT_S, SIM_DT_S)
    out = ENGINES[engine](
        fit,
        grid,
        t_cmd,
        np.ascontiguousarray(u_rad, dtype=np.float64),
        np.array(x0_rad, dtype=np.float64),
        fit.droop_rad * np.asarray(droop_mask, dtype=np.float64),
    )
    # step i covers (grid[i] - SIM_DT_S, grid[i]]: interpolate the readings between step ends
    pos = np.clip((np.asarray(t_read_s) - t0) / SIM_DT_S, 0.0, len(grid) - 1.0)
    i0 = np.minimum(pos.astype(np.int64), len(grid) - 2)
    f = (pos - i0)[:, None]
    return out[i0] * (1.0 - f) + out[i0 + 1] * f
