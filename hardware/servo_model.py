"""The one servo model: what a hobby servo does between a command and its horn (numpy only).

Six effects: command latency, dead band, first-order lag, rate limit, gravity droop and
quantisation. Three callers use them on two time bases, and the difference is deliberate:

* **Continuous time** (``ServoBank``): the emulator's servos and sysid's fitted model. A target
  takes effect ``command_latency_s`` after it was sent (``CommandDelay``, split to the instant);
  the horn moves towards ``target + droop`` with an exact first-order step, no faster than the
  rate limit, and not while the error is inside the dead band (``lag_step``); the *reading* is
  quantised (``quantise``).
* **Per control step** (``StepServo``): the simulator's actuation. MuJoCo's position actuator is
  the lag and gravity is the droop, so the model shapes the *target* once per control step: a
  latency of whole steps, a dead band on the change since the last applied target, the rate
  limit, then quantisation of the target (a PWM servo is driven in whole microseconds).

Everything here is plain numpy so the deploy computer needs nothing heavier. sysid keeps a
compiled integrator for speed; ``tests/sim2real/sysid`` holds it equal to ``ServoBank``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from hardware.errors import SpecError
from hardware.spec import ArmSpec


def quantise(x_rad: np.ndarray, resolution_rad: float) -> np.ndarray:
    """Round to the nearest multiple of ``resolution_rad`` (0: unchanged; ties to even)."""
    if resolution_rad <= 0:
        return x_rad
    return np.rint(x_rad / resolution_rad) * resolution_rad


def lag_step(
    pos_rad: np.ndarray,
    goal_rad: np.ndarray,
    dt_s: float,
    time_constant_s: float,
    max_speed_rad_s: np.ndarray | float,
    deadband_rad: float,
    active: np.ndarray | None = None,
) -> np.ndarray:
    """The move (n,) of one exact first-order step of length ``dt_s`` towards ``goal_rad``,
    capped at ``max_speed_rad_s * dt_s`` (a time constant of 0: no lag, the rate limit alone);
    zero where the error is inside the dead band or where ``active`` is False (torque off)."""
    err = goal_rad - pos_rad
    moving = np.abs(err) > deadband_rad
    if active is not None:
        moving &= active
    move = err * (1.0 - np.exp(-dt_s / time_constant_s)) if time_constant_s > 0 else err
    vmax_dt = np.multiply(max_speed_rad_s, dt_s)
    return np.clip(move, -vmax_dt, vmax_dt) * moving


class CommandDelay:
    """A dead time on commands, in continuous time: targets queue with the instant they take
    effect, and ``segments`` splits an interval where they come due, so the result is exact
    (and continuous in the latency, which a fit needs) rather than rounded to a step."""

    def __init__(self) -> None:
        self.in_force: np.ndarray | None = None  # None: no command has taken effect yet
        self._pending: deque[tuple[float, np.ndarray]] = deque()  # (effective at s, target)

    def last(self) -> np.ndarray | None:
        """The newest target received, due or not."""
        return self._pending[-1][1] if self._pending else self.in_force

    def push(self, effective_s: float, target_rad: np.ndarray) -> None:
        self._pending.append((effective_s, np.array(target_rad, dtype=float)))

    def clear(self) -> None:
        self._pending.clear()
        self.in_force = None

    def segments(self, t_from_s: float, t_to_s: float) -> Iterator[tuple[float, np.ndarray | None]]:
        """``(duration_s, target in force)`` pieces covering ``(t_from_s, t_to_s]``."""
        t = t_from_s
        while self._pending and self._pending[0][0] <= t_to_s:
            due_s, queued = self._pending.popleft()
            if due_s > t:
                yield due_s - t, self.in_force
                t = due_s
            self.in_force = queued
        yield t_to_s - t, self.in_force


@dataclass(frozen=True)
class ServoParams:
    """Parameters of n servos in continuous time (the emulator's and sysid's)."""

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
    """The true state of n servos in continuous time. Not thread-safe on its own: the emulator
    locks around it."""

    def __init__(self, params: ServoParams, initial_rad: np.ndarray, seed: int = 0) -> None:
        self.p = params
        self.pos = np.array(initial_rad, dtype=float)
        self.vel = np.zeros_like(self.pos)
        self.effort = np.zeros_like(self.pos)  # proxy for load, [-1, 1]
        self._rng = np.random.default_rng(seed)
        self.delay = CommandDelay()
        # Set by ``attach_body``: where an outside body (the mock world's physics) holds the horns.
        self.body_rad: np.ndarray | None = None
        self.body_vel_rad_s = np.zeros_like(self.pos)
        # Jammed servos (a stripped gear wedged, a cable caught): the horn stays where it is
        # whatever the command, and the motor pushes against it (full effort).
        self.jammed = np.zeros(self.pos.shape, dtype=bool)

    def jam(self, mask: np.ndarray) -> None:
        """From now on the servos in ``mask`` (n,) bool do not move; ``jam(zeros)`` frees them."""
        self.jammed = np.asarray(mask, dtype=bool).copy()

    def attach_body(self) -> None:
        """From now on an outside body moves the horns: the mock world's MuJoCo arm, whose
        torque-limited position actuators are the servo's lag, its stall under load and its sag
        under gravity. ``pos`` becomes the servo's drive setpoint (latency, dead band and the rate
        limit, no lag of its own), ``sense`` reports where the horns really are, and the readings
        come from there."""
        self.body_rad = self.pos.copy()

    def sense(self, body_rad: np.ndarray, body_vel_rad_s: np.ndarray) -> None:
        """Where the attached body holds the horns now. (An unpowered servo's setpoint stays
        where it was: the body holds the horn there, as a hobby servo's gear train does.)"""
        assert self.body_rad is not None, "sense() needs attach_body() first"
        self.body_rad[:] = body_rad
        self.body_vel_rad_s[:] = body_vel_rad_s

    @property
    def horn_rad(self) -> np.ndarray:
        """The physical horn angles: the body's where one is attached, else the model's."""
        return self.pos if self.body_rad is None else self.body_rad

    @property
    def horn_vel_rad_s(self) -> np.ndarray:
        return self.vel if self.body_rad is None else self.body_vel_rad_s

    def advance(
        self, t_from_s: float, t_to_s: float, target_rad: np.ndarray, powered: np.ndarray
    ) -> None:
        """Integrate from ``t_from_s`` to ``t_to_s`` with ``target_rad`` commanded since
        ``t_from_s``: with a command latency the target joins the delay line and takes effect
        ``command_latency_s`` later. The first target is in force at once (the power-on goal).
        Power (torque enable) acts at once."""
        target = np.asarray(target_rad, dtype=float)
        latency = self.p.command_latency_s
        if latency <= 0:
            self.step(t_to_s - t_from_s, target, powered)
            return
        last = self.delay.last()
        if last is None:
            self.delay.in_force = target.copy()
        elif not np.array_equal(last, target):
            self.delay.push(t_from_s + latency, target)
        self.run(t_from_s, t_to_s, powered)

    def run(self, t_from_s: float, t_to_s: float, powered: np.ndarray) -> None:
        """Integrate over ``(t_from_s, t_to_s]`` on what the delay line holds; nothing moves
        while no command has taken effect."""
        for dt_s, in_force in self.delay.segments(t_from_s, t_to_s):
            if in_force is not None:
                self.step(dt_s, in_force, powered)

    def drop_pending(self) -> None:
        """Forget queued targets (the device rebooted: what it had received is gone)."""
        self.delay.clear()

    def step(self, dt_s: float, target_rad: np.ndarray, powered: np.ndarray) -> None:
        if dt_s <= 0:
            return
        goal = np.asarray(target_rad, dtype=float) + self.p.droop_rad
        on = np.asarray(powered, dtype=bool)
        err = goal - self.horn_rad
        move = lag_step(
            self.pos,
            goal,
            dt_s,
            self.p.time_constant_s if self.body_rad is None else 0.0,
            self.p.max_speed_rad_s,
            self.p.deadband_rad,
            on,
        )
        move = np.where(self.jammed, 0.0, move)
        self.pos = self.pos + move
        self.vel = move / dt_s
        self.effort = np.where(on, np.clip(err / 0.2, -1.0, 1.0), 0.0)
        self.effort = np.where(on & self.jammed & (np.abs(err) > 0), np.sign(err), self.effort)

    def reading_rad(self) -> np.ndarray:
        """What the servo's sensor reports: quantised, with noise."""
        r = self.horn_rad
        if self.p.noise_rad > 0:
            r = r + self._rng.normal(0.0, self.p.noise_rad, size=r.shape)
        return quantise(r, self.p.resolution_rad)


class StepServo:
    """The same servo seen once per control step, shaping the actuator target (n,): latency in
    whole steps, dead band on the change, rate limit, quantisation. Hot path: plain ufuncs."""

    def __init__(self, n: int, max_speed_rad_s: float, control_dt_s: float) -> None:
        self._n = n
        self._max_speed_rad_s = max_speed_rad_s
        self._dt_s = control_dt_s
        self.set()
        self.reset(np.zeros(n))

    def set(
        self,
        latency_steps: int = 0,
        max_speed_scale: float = 1.0,
        deadband_rad: float = 0.0,
        resolution_rad: float = 0.0,
    ) -> None:
        """New parameters; they take effect at the next ``reset``'s latency fill."""
        self.latency_steps = int(latency_steps)
        self.max_step_rad = self._max_speed_rad_s * max_speed_scale * self._dt_s
        self.deadband_rad = float(deadband_rad)
        self.quantum_rad = float(resolution_rad)
        self.per_quantum = 1.0 / self.quantum_rad if self.quantum_rad > 0 else 0.0

    def reset(self, targets_rad: np.ndarray) -> None:
        """Start at rest on ``targets_rad``, with the latency line full of it."""
        self.applied_rad = np.array(targets_rad, dtype=float)
        # The latency line as a ring (latency_steps, n) and its head, in arrays: the envs' compiled
        # step (``sim2real.envs.fused.actuate``) advances this same state in place.
        self.queue_rad = np.tile(self.applied_rad, (self.latency_steps, 1))
        self.head = np.zeros(1, dtype=np.int64)

    def step(self, cmd_rad: np.ndarray) -> np.ndarray:
        """The actuator target for this step, given this step's command."""
        if self.latency_steps:
            h = int(self.head[0])
            due = self.queue_rad[h].copy()
            self.queue_rad[h] = cmd_rad
            self.head[0] = (h + 1) % self.latency_steps
            cmd_rad = due
        delta = cmd_rad - self.applied_rad
        if self.deadband_rad > 0:
            delta *= np.abs(delta) >= self.deadband_rad
        np.minimum(delta, self.max_step_rad, out=delta)
        np.maximum(delta, -self.max_step_rad, out=delta)
        out = self.applied_rad + delta
        if self.quantum_rad > 0:
            # ``quantise`` by the reciprocal: the same rounding but for last-bit ties, and the
            # bits the trained policies saw (pinned by tests/sim2real/randomization)
            out = np.rint(out * self.per_quantum) * self.quantum_rad
        self.applied_rad = out
        return out


def arrival_time_s(
    spec: ArmSpec,
    start_rad: np.ndarray,
    goal_rad: np.ndarray,
    tolerance_rad: float,
    command_speed_rad_s: float | None = None,
    dt_s: float = 0.001,
    max_s: float = 30.0,
) -> np.ndarray:
    """How long (n_actuators,) after a move's first command a healthy servo of ``spec`` sits
    within ``tolerance_rad`` of ``goal_rad``, from rest at ``start_rad``: the command slewed at
    the servo's speed (as the arm3 firmware slews its output), then the latency, the lag, the
    rate limit and the dead band of the one servo model. What the host waits for a joint whose
    reading is its own command (``feedback: commanded``): it cannot see the horn arrive. A host
    that ramps its commands slower passes ``command_speed_rad_s``."""
    params = ServoParams.from_spec(spec)
    start = np.asarray(start_rad, dtype=float)
    goal = np.asarray(goal_rad, dtype=float)
    vmax = params.max_speed_rad_s
    vcmd = vmax if command_speed_rad_s is None else np.minimum(vmax, command_speed_rad_s)
    cmd = start.copy()
    pos = start.copy()
    done = np.abs(goal - pos) <= tolerance_rad
    out = np.zeros_like(pos)
    steps = int(max_s / dt_s)
    for k in range(1, steps + 1):
        if done.all():
            break
        cmd = cmd + np.clip(goal - cmd, -vcmd * dt_s, vcmd * dt_s)
        pos = pos + lag_step(pos, cmd, dt_s, params.time_constant_s, vmax, params.deadband_rad)
        now = (np.abs(goal - pos) <= tolerance_rad) & (cmd == goal) & ~done
        out[now] = k * dt_s
        done |= now
    out[~done] = max_s
    return out + spec.servo.latency_s
