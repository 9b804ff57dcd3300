"""Servo dynamics of the emulator: what a hobby servo does with a target, kept cheap.

Per actuator, per step: an optional command latency (a new target takes effect a fixed dead time
after the device received it), a deadband (errors smaller than it are ignored), a first-order lag
with time constant tau, a rate limit (max speed), optional gravity droop (a constant sag on the
pitch joints while powered), quantisation of the reading, optional reading noise. All vectorised:
one step of four servos costs a few numpy calls.
"""

from __future__ import annotations

import math
from collections import deque
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
    command_latency_s: float = 0.0  # dead time between receiving a target and acting on it

    def __post_init__(self) -> None:
        if not (math.isfinite(self.command_latency_s) and self.command_latency_s >= 0):
            raise SpecError(
                f"command_latency_s must be finite and >= 0, got {self.command_latency_s!r}"
            )

    @classmethod
    def from_spec(
        cls,
        spec: ArmSpec,
        droop_rad: float = 0.0,
        noise_rad: float = 0.0,
        command_latency_s: float = 0.0,
    ) -> ServoParams:
        """Joints from ``spec.servo``, the gripper from ``spec.gripper``. Droop acts on the two
        pitch joints (shoulder, elbow), downwards (negative), ``droop_rad`` each. The command
        latency is not taken from ``spec.servo.latency_s``: that is what the sim is trained
        with, while the emulator's latency is a test knob (default 0, as before it existed)."""
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
            command_latency_s=command_latency_s,
        )


class ServoBank:
    """The true state of n servos. Not thread-safe on its own: the emulator locks around it."""

    def __init__(self, params: ServoParams, initial_rad: np.ndarray, seed: int = 0) -> None:
        self.p = params
        self.pos = np.array(initial_rad, dtype=float)
        self.vel = np.zeros_like(self.pos)
        self.effort = np.zeros_like(self.pos)  # proxy for load, [-1, 1]
        self._rng = np.random.default_rng(seed)
        self._in_force: np.ndarray | None = None  # the target the servos act on now
        self._pending: deque[tuple[float, np.ndarray]] = deque()  # (effective at s, target)

    def advance(
        self, t_from_s: float, t_to_s: float, target_rad: np.ndarray, powered: np.ndarray
    ) -> None:
        """Integrate from ``t_from_s`` to ``t_to_s`` with ``target_rad`` commanded since
        ``t_from_s``: with a command latency the target joins a FIFO and takes effect
        ``command_latency_s`` later, so the interval is split where queued targets come due.
        Power (torque enable) acts at once."""
        target = np.asarray(target_rad, dtype=float)
        latency = self.p.command_latency_s
        if latency <= 0:
            self.step(t_to_s - t_from_s, target, powered)
            return
        last = self._pending[-1][1] if self._pending else self._in_force
        if last is None:
            self._in_force = target.copy()  # power-on goal: in force from the start
        elif not np.array_equal(last, target):
            self._pending.append((t_from_s + latency, target.copy()))
        assert self._in_force is not None
        t = t_from_s
        while self._pending and self._pending[0][0] <= t_to_s:
            due_s, queued = self._pending.popleft()
            if due_s > t:
                self.step(due_s - t, self._in_force, powered)
                t = due_s
            self._in_force = queued
        self.step(t_to_s - t, self._in_force, powered)

    def drop_pending(self) -> None:
        """Forget queued targets (the device rebooted: what it had received is gone)."""
        self._pending.clear()
        self._in_force = None

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
