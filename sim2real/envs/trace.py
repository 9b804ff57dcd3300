"""Trace: follow a straight weld seam drawn on the table at a fixed stand-off (the seed
project's next mission). This file is the whole task: sampling, reward and success."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from sim2real import model as names
from sim2real.envs.base import Sensed, Task, register_task
from sim2real.observation import ObsField

if TYPE_CHECKING:
    from sim2real.envs.base import Arm3Env

STANDOFF_M = 0.025  # tool height above the seam (a torch's stand-off)
APPROACH_STEPS = 10  # steps to reach the seam start before the target starts moving
SUCCESS_MEAN_ERROR_M = 0.015


@register_task
class TraceTask(Task):
    name = "trace"
    scene = "trace"
    success_threshold_m = SUCCESS_MEAN_ERROR_M
    # Steering on the commanded pose keeps a tracker stable under camera and servo lag (reach).
    command_fields = True

    def __init__(self) -> None:
        self.start_m = np.zeros(3)
        self.dir = np.array([1.0, 0.0, 0.0])
        self.target_m = np.zeros(3)
        self.velocity_m_s = np.zeros(3)
        self._err_sum_m = 0.0
        self._err_n = 0

    def reset(self, env: Arm3Env, rng: np.random.Generator) -> None:
        spec = env.spec_arm
        L = names.SEAM_LENGTH_M
        for _ in range(1000):
            r, a = rng.uniform(0.11, 0.2), rng.uniform(-0.6, 0.6)
            start = np.array([r * np.cos(a), r * np.sin(a), STANDOFF_M])
            heading = rng.uniform(-np.pi, np.pi)
            d = np.array([np.cos(heading), np.sin(heading), 0.0])
            if all(
                spec.inverse_kinematics(start + s * L * d) is not None for s in np.linspace(0, 1, 5)
            ):
                break
        self.start_m, self.dir = start, d
        m = env.model
        seam = m.body_mocapid[m.body(names.SEAM_BODY).id]
        env.data.mocap_pos[seam] = (start[0], start[1], 0.0003)
        env.data.mocap_quat[seam] = (np.cos(heading / 2), 0.0, 0.0, np.sin(heading / 2))
        self._err_sum_m, self._err_n = 0.0, 0
        self._move_target(env, 0)

    def _move_target(self, env: Arm3Env, step: int) -> None:
        track_steps = max(1, env.max_episode_steps - APPROACH_STEPS)
        s = np.clip((step - APPROACH_STEPS) / track_steps, 0.0, 1.0)
        self.target_m = self.start_m + s * names.SEAM_LENGTH_M * self.dir
        moving = APPROACH_STEPS <= step < env.max_episode_steps
        speed = names.SEAM_LENGTH_M / (track_steps * env.control_dt_s)
        self.velocity_m_s = self.dir * speed if moving else np.zeros(3)
        env.data.mocap_pos[0] = self.target_m

    def after_step(self, env: Arm3Env) -> None:
        if env.steps + 1 > APPROACH_STEPS:  # env.steps is incremented after this hook
            self._err_sum_m += float(np.linalg.norm(env.ee_position() - self.target_m))
            self._err_n += 1
        self._move_target(env, env.steps + 1)

    def true_points(self, env: Arm3Env) -> np.ndarray:
        return self.target_m[None]

    def goals(self, env: Arm3Env, sensed: Sensed) -> tuple[np.ndarray, np.ndarray]:
        return sensed.ee_m, sensed.points_m[0]

    def true_goals(self, env: Arm3Env) -> tuple[np.ndarray, np.ndarray]:
        return env.ee_position(), self.target_m

    def extra_fields(self) -> tuple[ObsField, ...]:
        return (ObsField("goal_vel", 3, "m/s", "velocity of the seam point to follow"),)

    def extra_readings(self, env: Arm3Env, sensed: Sensed) -> dict[str, np.ndarray]:
        return {"goal_vel": self.velocity_m_s}

    def success_from_distance(self, env: Arm3Env, distance_m: float) -> bool:
        """Mean tracking error along the seam, not the last step's distance."""
        if self._err_n == 0:
            return False
        return self._err_sum_m / self._err_n < SUCCESS_MEAN_ERROR_M

    @property
    def mean_tracking_error_m(self) -> float:
        return self._err_sum_m / max(self._err_n, 1)
