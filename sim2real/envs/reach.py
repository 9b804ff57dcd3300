"""Reach: bring the tool within 1 cm of a target sampled in the reachable workspace."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from hardware.spec import ArmSpec
from sim2real.envs.base import Task, register_task
from sim2real.envs.reach_contract import ReachContract
from sim2real.envs.workspace import LIMIT_MARGIN_RAD, MIN_HEIGHT_M, MIN_RADIUS_M

if TYPE_CHECKING:
    from sim2real.envs.base import Arm3Env


class ReachableSampler:
    """``workspace.sample_reachable`` with the spec's arrays and constants taken once: the same
    draws (``uniform(lo, hi)`` is ``lo + (hi - lo) * random(3)`` in numpy), the same forward
    kinematics in the same operations, so the same targets and generator state, at a fraction of
    the per-reset cost (``tests/sim2real/envs/test_reach_sampler.py``)."""

    def __init__(self, spec: ArmSpec, min_height_m: float = MIN_HEIGHT_M) -> None:
        self.spec = spec
        self._lo = spec.lower_rad + LIMIT_MARGIN_RAD
        self._span = (spec.upper_rad - LIMIT_MARGIN_RAD) - self._lo
        self._signs = tuple(j.sign for j in spec.joints[:3])
        L = spec.links
        self._links = (L.upper_arm_m, L.forearm_m, L.tool_forward_m, L.base_height_m)
        self._tool_down_m = L.tool_down_m
        self._min_height_m = min_height_m

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        s0, s1, s2 = self._signs
        upper, fore, fwd, base = self._links
        for _ in range(1000):
            q0, q1, q2 = (self._lo + self._span * rng.random(3)).tolist()
            yaw = s0 * q0
            a1 = s1 * q1
            a12 = a1 + s2 * q2
            r = upper * math.sin(a1) + fore * math.cos(a12) + fwd
            z = base + upper * math.cos(a1) - fore * math.sin(a12)
            z -= self._tool_down_m
            x, y = r * math.cos(yaw), r * math.sin(yaw)
            if z >= self._min_height_m and np.hypot(x, y) >= MIN_RADIUS_M:
                return np.array([x, y, z])
        raise RuntimeError(
            f"spec {self.spec.name!r}: no reachable point above {self._min_height_m} m found"
        )


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
        self._sampler: ReachableSampler | None = None

    def placement(self, env: Arm3Env) -> dict[str, np.ndarray]:
        return {"target": self.target_m.copy()}

    def reset(self, env: Arm3Env, rng: np.random.Generator) -> None:
        if self._sampler is None or self._sampler.spec is not env.spec_arm:
            self._sampler = ReachableSampler(env.spec_arm)
        self.target_m = self._sampler.sample(rng)
        env.data.mocap_pos[0] = self.target_m

    def true_points(self, env: Arm3Env) -> np.ndarray:
        return self.target_m[None]

    def true_goals(self, env: Arm3Env) -> tuple[np.ndarray, np.ndarray]:
        return env.ee_position(), self.target_m
