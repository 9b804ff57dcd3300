"""Excite an arm with a step pattern that makes every servo parameter visible, and log it.

Big steps expose the speed limit, medium steps the lag, a staircase of small steps the dead band,
long holds the droop. Works on any ``hardware.Arm`` (emulator, SimArm, a real bus).
"""

from __future__ import annotations

import io
import time
from pathlib import Path

import numpy as np

from hardware.arm import ArmBase

# (offset from home in rad, hold time in s); joints alternate the sign so they do not all lift.
PATTERN: tuple[tuple[float, float], ...] = (
    (0.0, 0.3),
    (1.0, 0.6),
    (0.0, 0.6),
    (-0.3, 0.5),
    (0.0, 0.5),
    (0.05, 0.4),
    (0.0, 0.4),
    (-0.05, 0.4),
    (0.0, 0.4),
    (0.004, 0.3),
    (0.0, 0.3),
    (0.008, 0.3),
    (0.0, 0.3),
    (0.012, 0.3),
    (0.0, 0.3),
    (0.02, 0.3),
    (0.0, 0.3),
)


def record_excitation(
    arm: ArmBase, rate_hz: float = 100.0, repeats: int = 1
) -> dict[str, np.ndarray]:
    """Run the pattern about home; returns the log arrays (``t_s`` read time, ``joints_rad``,
    ``t_cmd_s``, ``sent_rad``)."""
    spec = arm.spec
    arm.home()
    home = arm.read_state().positions_rad.copy()
    signs = np.where(np.arange(spec.n_actuators) % 2 == 0, 1.0, -1.0)
    signs[spec.n_joints :] = 0.0  # the gripper stays put
    period = 1.0 / rate_hz
    rows: dict[str, list[np.ndarray | float]] = {
        k: [] for k in ("t_s", "joints_rad", "t_cmd_s", "sent_rad")
    }
    next_t = time.monotonic()
    for _ in range(repeats):
        for offset, hold_s in PATTERN:
            target = home + signs * offset
            for _ in range(max(1, round(hold_s * rate_hz))):
                # Stamp before each call: the device samples / applies when the request
                # arrives, a fixed wire time later (the fitted latency absorbs it), while the
                # time the reply takes to come back varies with load.
                rows["t_s"].append(time.monotonic())
                state = arm.read_state()
                rows["joints_rad"].append(state.positions_rad)
                rows["t_cmd_s"].append(time.monotonic())
                rows["sent_rad"].append(arm.command(target))
                next_t += period
                time.sleep(max(0.0, next_t - time.monotonic()))
    return {k: np.asarray(v, dtype=float) for k, v in rows.items()}


def save_log(path: Path, log: dict[str, np.ndarray]) -> Path:
    from hardware.atomic import atomic_write_bytes

    buf = io.BytesIO()
    np.savez_compressed(buf, **log)
    return atomic_write_bytes(path, buf.getvalue())
