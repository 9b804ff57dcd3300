"""Training-side wrappers: discrete actions for DQN, and two that only training ever sees
(an action-rate penalty and a start-state curriculum); evaluation and deployment build bare envs.

Discrete actions: N table rows, each a normalised joint-target delta.

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


# Keys of the ``start_curriculum`` preset mapping.
START_CURRICULUM_KEYS: tuple[str, ...] = ("held_prob",)


def check_held_prob(p: Any) -> float:
    """The one check of ``start_curriculum.held_prob``: the config (before anything is written)
    and the wrapper (built directly) share it."""
    if isinstance(p, bool) or not isinstance(p, int | float) or not 0.0 <= p <= 1.0:
        raise ConfigError(f"start_curriculum.held_prob must be in [0, 1], got {p!r}")
    return float(p)


class StartCurriculum(gym.Wrapper[Any, Any, Any, Any]):
    """Training-only reset curriculum: with probability ``held_prob`` an episode starts with the
    object already grasped (``reset(options={"start": "held"})``), otherwise as the task starts.

    Reset from demonstration states (Nair et al. 2018; robosuite's demo sampler): a 54-minute PPO
    run on pick learned to close on the cube but never lifted it, as a grasp found by chance is
    rarely held long enough to learn what lifting pays; started in the grasp, every update sees
    lifts. The draw has its own generator, seeded from the reset seed, so an env reset with a
    given seed gets the same DR and cube placement as without the wrapper. Training success
    rates include the held starts; evaluation never sees them.
    """

    def __init__(self, env: gym.Env[Any, Any], held_prob: float) -> None:
        super().__init__(env)
        held_prob = check_held_prob(held_prob)
        from sim2real.envs.base import START_HELD

        task = getattr(env.unwrapped, "task", None)
        if START_HELD not in getattr(task, "start_modes", ()):
            name = getattr(task, "name", type(env.unwrapped).__name__)
            raise ConfigError(f"start_curriculum: task {name!r} has no {START_HELD!r} start")
        self.held_prob = held_prob
        self._start_held = START_HELD
        self._rng = np.random.default_rng(0)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            self._rng = np.random.default_rng([seed, 0x5742])  # not the env's own stream
        opts = dict(options or {})
        if "start" not in opts and self._rng.random() < self.held_prob:
            opts["start"] = self._start_held
        return self.env.reset(seed=seed, options=opts or None)


# The env's documented info key for its privileged state (``kuka_grasp.PRIVILEGED_INFO_KEY``).
PRIVILEGED_INFO_KEY = "privileged_state"


class PrivilegedObservation(gym.Wrapper[Any, Any, Any, Any]):
    """Training-only: the observation becomes ``{"pixels": obs, "privileged": info[...]}``, or,
    for an env that already observes a ``Dict`` (a frame and proprioception), that ``Dict`` with
    ``"privileged"`` added.

    The env reports its privileged state (object positions and the like) in ``info`` at reset and
    at every step, beside an observation that never contains it; only this wrapper, which the
    trainer adds for an asymmetric critic or a DAgger teacher, moves it into the observation.
    Evaluation and deployment build bare envs, so a policy's actor cannot come to rely on it.
    """

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        from sim2real.train.augment import PIXELS_KEY, PRIVILEGED_KEY

        space = getattr(env.unwrapped, "privileged_space", None)
        if not isinstance(space, gym.spaces.Box):
            raise ConfigError(
                f"{type(env.unwrapped).__name__} reports no privileged state "
                f"(info[{PRIVILEGED_INFO_KEY!r}]); asymmetric critics and distillation need one"
            )
        inner = env.observation_space
        self._keyed = isinstance(inner, gym.spaces.Dict)
        spaces = dict(inner.spaces) if isinstance(inner, gym.spaces.Dict) else {PIXELS_KEY: inner}
        if PRIVILEGED_KEY in spaces:
            raise ConfigError(f"the observation already has a {PRIVILEGED_KEY!r} key: {inner}")
        self._pixels, self._privileged = PIXELS_KEY, PRIVILEGED_KEY
        self.observation_space = gym.spaces.Dict({**spaces, PRIVILEGED_KEY: space})

    def _obs(self, obs: Any, info: dict[str, Any]) -> dict[str, Any]:
        keyed = dict(obs) if self._keyed else {self._pixels: obs}
        return {**keyed, self._privileged: info[PRIVILEGED_INFO_KEY]}

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        return self._obs(obs, info), info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, term, trunc, info = self.env.step(action)
        return self._obs(obs, info), float(reward), term, trunc, info
