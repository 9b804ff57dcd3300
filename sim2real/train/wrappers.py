"""Discrete actions for DQN: N table rows, each a normalised joint-target delta.

The seed project drove its arm with "+/- per axis plus no-op"; this is the same idea over any
env of the family. Rows are: no-op, then +m and -m for each joint and each magnitude m. When the
task uses a gripper (its last action is an absolute opening), the joint rows exist twice, once
with the gripper open and once closed, so the table stays stateless: the exported policy is still
a pure function of the observation.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from sim2real.errors import ConfigError

DEFAULT_MAGNITUDES: tuple[float, ...] = (1.0, 0.2)  # coarse moves, then ~2 mm corrections


def delta_action_table(
    n_joints: int, magnitudes: Sequence[float] = DEFAULT_MAGNITUDES, gripper: bool = False
) -> np.ndarray:
    """(N, n_joints [+1]) float32 table of normalised actions."""
    mags = [float(m) for m in magnitudes]
    if not mags or any(not 0.0 < m <= 1.0 for m in mags):
        raise ConfigError(f"discrete magnitudes {list(magnitudes)} must be in (0, 1]")
    joint_rows = [np.zeros(n_joints)]
    for j in range(n_joints):
        for m in mags:
            for sign in (1.0, -1.0):
                row = np.zeros(n_joints)
                row[j] = sign * m
                joint_rows.append(row)
    if not gripper:
        return np.array(joint_rows, dtype=np.float32)
    rows = [np.append(r, g) for g in (1.0, -1.0) for r in joint_rows]
    return np.array(rows, dtype=np.float32)


class DiscreteDeltaActions(gym.ActionWrapper[Any, np.int64, np.ndarray]):
    """Maps ``Discrete(N)`` to the wrapped env's ``Box`` action through a fixed table."""

    def __init__(self, env: gym.Env[Any, Any], table: np.ndarray) -> None:
        super().__init__(env)
        box = env.action_space
        if not isinstance(box, gym.spaces.Box) or box.shape is None or len(box.shape) != 1:
            raise ConfigError(f"DiscreteDeltaActions needs a 1-D Box action space, got {box}")
        table = np.asarray(table, dtype=np.float32)
        if table.ndim != 2 or table.shape[1] != box.shape[0]:
            raise ConfigError(
                f"action table shape {table.shape} does not match action space {box.shape}"
            )
        if np.any(table < box.low) or np.any(table > box.high):
            raise ConfigError("action table rows leave the action space bounds")
        self.table = table
        self.action_space = gym.spaces.Discrete(len(table))

    def action(self, action: Any) -> np.ndarray:
        return self.table[int(action)]


class ActionRatePenalty(gym.Wrapper[Any, Any, Any, Any]):
    """Training-only reward shaping: ``-coef * ||a_t - a_{t-1}||^2`` (normalised actions).

    Smooth commands are what a real servo bus wants, and a policy that stops twitching near the
    target tolerates more latency than it was trained with: the same trick as the action-rate
    terms of legged-robot sim-to-real work. Evaluation and deployment never see this wrapper.
    """

    def __init__(self, env: gym.Env[Any, Any], coef: float) -> None:
        super().__init__(env)
        if not coef >= 0.0:
            raise ConfigError(f"action_rate_penalty {coef} must be >= 0")
        self.coef = float(coef)
        self._prev: np.ndarray | None = None

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        self._prev = None
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, term, trunc, info = self.env.step(action)
        a = np.asarray(action, dtype=np.float64)
        prev = np.zeros_like(a) if self._prev is None else self._prev
        self._prev = a
        return obs, float(reward) - self.coef * float(np.sum((a - prev) ** 2)), term, trunc, info
