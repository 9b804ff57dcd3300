"""Reach: bring the tool within 1 cm of a target sampled in the reachable workspace."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from sim2real.envs.base import Sensed, Task, register_task
from sim2real.envs.contract import DeployContract, Outcome, Percept, View, need
from sim2real.envs.workspace import sample_reachable

if TYPE_CHECKING:
    from sim2real.envs.base import Arm3Env


SUCCESS_M = 0.01


class ReachContract(DeployContract):
    """Outside the simulator: the target plate is where a person (or the mock world) put it;
    success is the tool within 1 cm of it at the end, as in training."""

    task = "reach"
    objects = ("target",)

    def setup(self) -> None:
        self._distance_m = float("nan")

    def placement(self, rng: np.random.Generator) -> dict[str, np.ndarray]:
        return {"target": sample_reachable(self.spec, rng)}

    def readings(self, percept: Percept, step: int) -> dict[str, np.ndarray]:
        tool, target = need(percept, "target")
        return {"ee_pos": tool, "goal_pos": target, "goal_delta": target - tool}

    def goal_m(self, percept: Percept, step: int) -> np.ndarray | None:
        return percept.position("target")

    def score(self, view: View, step: int) -> str | None:
        self._distance_m = float(np.linalg.norm(view.tool_m - view.objects["target"]))
        return None

    def outcome(self) -> Outcome:
        d = self._distance_m
        return Outcome(d < SUCCESS_M, d, {"final_distance_m": d})


@register_task
class ReachTask(Task):
    name = "reach"
    scene = "reach"
    # Steering on the commanded pose survives latency unseen in training (docs/training.md).
    command_fields = True
    contract = ReachContract

    def __init__(self) -> None:
        self.target_m = np.zeros(3)

    def reset(self, env: Arm3Env, rng: np.random.Generator) -> None:
        self.target_m = sample_reachable(env.spec_arm, rng)
        env.data.mocap_pos[0] = self.target_m

    def true_points(self, env: Arm3Env) -> np.ndarray:
        return self.target_m[None]

    def goals(self, env: Arm3Env, sensed: Sensed) -> tuple[np.ndarray, np.ndarray]:
        return sensed.ee_m, sensed.points_m[0]

    def true_goals(self, env: Arm3Env) -> tuple[np.ndarray, np.ndarray]:
        return env.ee_position(), self.target_m
