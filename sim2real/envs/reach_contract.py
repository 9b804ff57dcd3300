"""Reach outside the simulator: its deploy contract. Apart from the task (``reach.py``, which
imports MuJoCo through the env) so that the deploy runtime runs a reach policy without MuJoCo."""

from __future__ import annotations

import numpy as np

from sim2real.envs.contract import DeployContract, Outcome, Percept, View, need
from sim2real.envs.workspace import sample_reachable

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
