"""Servo dynamics of the emulator: what a hobby servo does with a target, kept cheap.

Per actuator, per step: a deadband (errors smaller than it are ignored), a first-order lag with
time constant tau, a rate limit (max speed), optional gravity droop (a constant sag on the pitch
joints while powered), quantisation of the reading, optional reading noise. All vectorised: one
step of four servos costs a few numpy calls.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hardware.errors import SpecError
from hardware.spec import ArmSpec


@dataclass(frozen=True)
class ServoParams:
    max_speed_rad_s: np.ndarray  # (n,)
    time_constant_s: float
    deadband_rad: float
    resolution_rad: float
    droop_rad: np.ndarray  # (n,) signed steady-state sag while powered
    noise_rad: float  # std of the reading noise

    @classmethod
    def from_spec(
        cls, spec: ArmSpec, droop_rad: float = 0.0, noise_rad: float = 0.0
    ) -> ServoParams:
        """Joints from ``spec.servo``, the gripper from ``spec.gripper``. Droop acts on the two
        pitch joints (shoulder, elbow), downwards (negative), ``droop_rad`` each."""
        if droop_rad < 0 or noise_rad < 0:
            raise SpecError(f"droop_rad and noise_rad must be >= 0, got {droop_rad}, {noise_rad}")
        speeds = [spec.servo.max_speed_rad_s] * spec.n_joints
        droop = [0.0] * spec.n_actuators
        for i, joint in enumerate(spec.joints):
            if joint.axis.lstrip("-") == "y":
                droop[i] = -droop_rad
        if spec.gripper is not None:
            speeds.append(spec.gripper.max_speed_rad_s)
        return cls(
            max_speed_rad_s=np.array(speeds, dtype=float),
            time_constant_s=spec.servo.time_constant_s,
            deadband_rad=spec.servo.deadband_rad,
            resolution_rad=spec.servo.resolution_rad,
            droop_rad=np.array(droop, dtype=float),
            noise_rad=noise_rad,
        )


class ServoBank:
    """The true state of n servos. Not thread-safe on its own: the emulator locks around it."""

    def __init__(self, params: ServoParams, initial_rad: np.ndarray, seed: int = 0) -> None:
        self.p = params
        self.pos = np.array(initial_rad, dtype=float)
        self.vel = np.zeros_like(self.pos)
        self.effort = np.zeros_like(self.pos)  # proxy for load, [-1, 1]
        self._rng = np.random.default_rng(seed)

    def step(self, dt_s: float, target_rad: np.ndarray, powered: np.ndarray) -> None:
        if dt_s <= 0:
            return
        goal = np.asarray(target_rad, dtype=float) + self.p.droop_rad
        err = goal - self.pos
        active = np.asarray(powered, dtype=bool) & (np.abs(err) > self.p.deadband_rad)
        # exact first-order response over dt, then the speed limit
        move = err * (1.0 - np.exp(-dt_s / self.p.time_constant_s))
        vmax_dt = self.p.max_speed_rad_s * dt_s
        move = np.clip(move, -vmax_dt, vmax_dt) * active
        self.pos = self.pos + move
        self.vel = move / dt_s
        self.effort = np.where(powered, np.clip(err / 0.2, -1.0, 1.0), 0.0)

    def reading_rad(self) -> np.ndarray:
        """What the servo's sensor reports: quantised, with noise."""
        r = self.pos
        if self.p.noise_rad > 0:
            r = r + self._rng.normal(0.0, self.p.noise_rad, size=r.shape)
        if self.p.resolution_rad > 0:
            r = np.round(r / self.p.resolution_rad) * self.p.resolution_rad
        return r
