"""Reach: bring the tool within 1 cm of a target sampled in the reachable workspace."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from sim2real.envs.base import Task, register_task
from sim2real.envs.reach_contract import ReachContract
from sim2real.envs.workspace import sample_reachable

if TYPE_CHECKING:
    from sim2real.envs.base import Arm3Env


@register_task
class ReachTask(Task):
    name = "reach"
    scene = "reach"
    # Steering on the commanded pose survives latency unseen in training (docs/training.md).
    command_fields = True
    contract = ReachContract

    def __init__(self) -> None:
        super().__init__()
        self.target_m = np.zeros(3)

    def reset(self, env: Arm3Env, rng: np.random.Generator) -> None:
        self.target_m = sample_reachable(env.spec_arm, rng)
        env.data.mocap_pos[0] = self.target_m

    def true_points(self, env: Arm3Env) -> np.ndarray:
        return self.target_m[None]

    def true_goals(self, env: Arm3Env) -> tuple[np.ndarray, np.ndarray]:
        return env.ee_position(), self.target_m
