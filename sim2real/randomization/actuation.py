"""Actuation DR: what a hobby servo does between the command and the horn.

Order per control step (as on the real bus): noise on the command → transport latency → the
servo's dead band (a change smaller than it does not move the horn) → speed limit → quantisation
to the servo's resolution. The result is the MuJoCo position-actuator target.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from typing import Any

import numpy as np

from hardware.spec import ArmSpec
from sim2real.randomization.base import ModelIds, NoiseBuffer
from sim2real.randomization.config import Range

Params = dict[str, Any]


def sample(rng: np.random.Generator, ranges: Mapping[str, Range], ids: ModelIds) -> Params:
    return {
        "latency_steps": round(float(ranges["latency_steps"].sample(rng))),
        "action_noise_rad": float(ranges["action_noise_rad"].sample(rng)),
        "max_speed_scale": float(ranges["max_speed_scale"].sample(rng)),
        "deadband_rad": float(ranges["deadband_rad"].sample(rng)),
        "quantisation_rad": float(ranges["quantisation_rad"].sample(rng)),
    }


class ServoActuation:
    """Turns commanded joint targets (n,) into actuator targets, one call per control step."""

    def __init__(self, spec: ArmSpec, control_dt_s: float, n: int) -> None:
        self._spec = spec
        self._dt = control_dt_s
        self._n = n
        self.configure(
            {
                "latency_steps": 0,
                "action_noise_rad": 0.0,
                "max_speed_scale": 1.0,
                "deadband_rad": 0.0,
                "quantisation_rad": 0.0,
            }
        )
        self._applied = np.zeros(n)
        self._queue: deque[np.ndarray] = deque()
        self._noise = NoiseBuffer(n)

    def configure(self, params: Params) -> None:
        self.latency_steps = int(params["latency_steps"])
        self.noise_rad = float(params["action_noise_rad"])
        self.max_step_rad = self._spec.servo.max_speed_rad_s * params["max_speed_scale"] * self._dt
        self.deadband_rad = float(params["deadband_rad"])
        self.quantum_rad = float(params["quantisation_rad"])

    def reset(self, targets_rad: np.ndarray) -> None:
        self._noise.clear()
        self._applied = np.array(targets_rad, dtype=float)
        self._queue = deque([self._applied.copy() for _ in range(self.latency_steps)])

    def __call__(self, targets_rad: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Hot path (every env step): plain ufuncs, no np.clip/np.where wrappers."""
        cmd = targets_rad
        if self.noise_rad > 0:
            cmd = cmd + self.noise_rad * self._noise.take(rng)
        if self.latency_steps:
            self._queue.append(cmd)
            cmd = self._queue.popleft()
        delta = cmd - self._applied
        if self.deadband_rad > 0:
            delta *= np.abs(delta) >= self.deadband_rad
        np.minimum(delta, self.max_step_rad, out=delta)
        np.maximum(delta, -self.max_step_rad, out=delta)
        out = self._applied + delta
        if self.quantum_rad > 0:
            out = np.rint(out * (1.0 / self.quantum_rad)) * self.quantum_rad
        self._applied = out
        return out
