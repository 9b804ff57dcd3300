"""The simulator's servo at run time: the one servo model (``hardware.servo_model.StepServo``)
on the control step's time base, with the command noise DR asks for in front of it.

It lives outside ``randomization/`` because the envs and ``deploy.SimArm`` run it every step;
DR only samples its parameters (``randomization.actuation.sample``) and hands them to
``configure``. Order per control step (as on the real bus): noise on the command → transport
latency → the servo's dead band → speed limit → quantisation to the servo's resolution. The
result is the MuJoCo position-actuator target.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from hardware.servo_model import StepServo
from hardware.spec import ArmSpec
from sim2real.noise import NoiseBuffer


class ServoActuation:
    """Turns commanded joint targets (n,) into actuator targets, one call per control step.
    Unconfigured it is the nominal servo: no latency, noise, dead band or quantisation, the
    datasheet speed."""

    def __init__(self, spec: ArmSpec, control_dt_s: float, n: int) -> None:
        self.servo = StepServo(n, spec.servo.max_speed_rad_s, control_dt_s)
        self.noise_rad = 0.0
        self.noise = NoiseBuffer(n)

    def configure(self, params: Mapping[str, Any]) -> None:
        """Apply DR's ``actuation`` parameters (``randomization.actuation.sample``)."""
        self.noise_rad = float(params["action_noise_rad"])
        self.servo.set(
            latency_steps=int(params["latency_steps"]),
            max_speed_scale=params["max_speed_scale"],
            deadband_rad=float(params["deadband_rad"]),
            resolution_rad=float(params["quantisation_rad"]),
        )

    def reset(self, targets_rad: np.ndarray) -> None:
        self.noise.clear()
        self.servo.reset(targets_rad)

    def __call__(self, targets_rad: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Hot path (every env step)."""
        cmd = targets_rad
        if self.noise_rad > 0:
            cmd = cmd + self.noise_rad * self.noise.take(rng)
        return self.servo.step(cmd)
