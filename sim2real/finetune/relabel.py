"""Hindsight goal relabelling for the online replay buffer (HER's "future" strategy,
Andrychowicz et al. 2017), on flat observations.

On an arm that is not its spec, a reach policy stops a centimetre or two short: it aims with
the spec's geometry. Each online step it takes still shows where an action really moves the
tool, so a batch transition whose goal is replaced by a position the tool reached later in the
same episode teaches the critic the plant's geometry whatever the episode's own outcome. The
relabelled goal is written into every goal-dependent field of the observation (the goal, and
each "goal minus X" field), and the reward is recomputed with the task's own reward, keeping the
training-only action-rate penalty the source was trained with (from the observation's last
action).

Episode boundaries need no protocol: inside an episode the loop sends ``next_obs[t]`` as
``obs[t+1]`` bit for bit, so a transition whose observation differs from the previous one's next
observation starts an episode. This also holds for a replay buffer reloaded on ``--resume``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim2real.errors import ConfigError
from sim2real.finetune.defaults import LEARNER_DEFAULTS

RewardFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class GoalFields:
    """Where a goal-conditioned task's goal sits in its flat observation (raw units)."""

    achieved: slice  # what the goal is compared with (reach: the tool estimate)
    goal: slice
    deltas: tuple[tuple[slice, slice], ...]  # (field, reference): field = goal - reference
    success_m: float
    reward_name: str
    prev_action: slice | None = None  # the last action, for the action-rate shaping

    def __post_init__(self) -> None:
        width = self.goal.stop - self.goal.start
        spans = [self.achieved, *(s for pair in self.deltas for s in pair)]
        if any(s.stop - s.start != width for s in spans):
            raise ConfigError(f"goal fields of unequal widths: {self}")
        if not self.success_m > 0:
            raise ConfigError(f"goal success radius {self.success_m!r} must be > 0 m")


def _slices(layout: Sequence[Mapping[str, Any]]) -> dict[str, slice]:
    return {str(f["name"]): slice(int(f["start"]), int(f["stop"])) for f in layout}


def _reach_fields(layout: Sequence[Mapping[str, Any]], reward_name: str) -> GoalFields:
    s = _slices(layout)
    need = ("ee_pos", "goal_pos", "goal_delta")
    missing = [n for n in need if n not in s]
    if missing:
        raise ConfigError(f"reach observation has no {missing} field to relabel")
    deltas = [(s["goal_delta"], s["ee_pos"])]
    if "target_goal_delta" in s and "target_ee_pos" in s:
        deltas.append((s["target_goal_delta"], s["target_ee_pos"]))
    from sim2real.envs.reach_contract import SUCCESS_M

    return GoalFields(
        s["ee_pos"], s["goal_pos"], tuple(deltas), SUCCESS_M, reward_name, s.get("prev_action")
    )


# task -> how its goal sits in the observation; a task not here cannot be relabelled
RELABEL_TASKS: dict[str, Callable[[Sequence[Mapping[str, Any]], str], GoalFields]] = {
    "reach": _reach_fields,
}


def default_ratio(config: Mapping[str, Any]) -> float:
    """``--relabel``'s default: the measured share for a task that can be relabelled, else 0."""
    return float(LEARNER_DEFAULTS["relabel"]) if str(config.get("task")) in RELABEL_TASKS else 0.0


def goal_fields(config: Mapping[str, Any]) -> GoalFields:
    """The source run's goal fields, or a ``ConfigError`` naming the task that has none."""
    task = str(config.get("task", ""))
    if task not in RELABEL_TASKS:
        raise ConfigError(
            f"goal relabelling is not defined for task {task!r}; it is for {sorted(RELABEL_TASKS)}"
        )
    layout = config.get("obs_layout")
    if not layout:
        raise ConfigError("the source run records no observation layout to relabel")
    reward = str(dict(config.get("env_kwargs") or {}).get("reward", "distance"))
    return RELABEL_TASKS[task](layout, reward)


class Relabeler:
    """Relabels a batch in place. Observations are stored normalised; ``scale``/``offset`` are
    the frozen normaliser's (identity when the run did not normalise)."""

    def __init__(
        self,
        fields: GoalFields,
        ratio: float,
        mean: np.ndarray | None,
        std: np.ndarray | None,
        penalty_coef: float = 0.0,
    ) -> None:
        if not 0.0 <= ratio <= 1.0:
            raise ConfigError(f"relabel ratio {ratio!r} must be in [0, 1]")
        from sim2real.envs.base import REWARDS

        if fields.reward_name not in REWARDS:
            raise ConfigError(f"reward {fields.reward_name!r}; valid: {sorted(REWARDS)}")
        if penalty_coef > 0 and fields.prev_action is None:
            raise ConfigError("an action-rate penalty to relabel needs a prev_action field")
        self.fields, self.ratio, self.penalty_coef = fields, float(ratio), float(penalty_coef)
        self._reward: RewardFn = REWARDS[fields.reward_name]
        self._mean = None if mean is None else np.asarray(mean, np.float64)
        self._std = None if std is None else np.asarray(std, np.float64)

    def _raw(self, x: np.ndarray, sl: slice) -> np.ndarray:
        v = np.asarray(x[:, sl], np.float64)
        if self._mean is None or self._std is None:
            return v
        return v * self._std[sl] + self._mean[sl]

    def _put(self, x: np.ndarray, sl: slice, raw: np.ndarray) -> None:
        if self._mean is not None and self._std is not None:
            raw = (raw - self._mean[sl]) / self._std[sl]
        x[:, sl] = raw

    def _task_reward(self, achieved: np.ndarray, goal: np.ndarray) -> np.ndarray:
        d = np.linalg.norm(achieved - goal, axis=-1)
        return np.asarray(self._reward(d, d < self.fields.success_m), np.float64)

    def relabel(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        actions: np.ndarray,
        future_next_obs: np.ndarray,
    ) -> np.ndarray:
        """Give rows ``obs[i], next_obs[i]`` the goal that ``future_next_obs[i]`` achieved (in
        place) and return the rewards that goal earns, the shaping penalty included. All
        arrays are the selected rows only."""
        f = self.fields
        new_goal = self._raw(future_next_obs, f.achieved)
        achieved = self._raw(next_obs, f.achieved)
        penalty = np.zeros(len(obs))
        if self.penalty_coef > 0 and f.prev_action is not None:
            prev = self._raw(obs, f.prev_action)
            penalty = self.penalty_coef * np.sum((np.asarray(actions, np.float64) - prev) ** 2, 1)
        for x in (obs, next_obs):
            self._put(x, f.goal, new_goal)
            for field, ref in f.deltas:
                self._put(x, field, new_goal - self._raw(x, ref))
        return self._task_reward(achieved, new_goal) - penalty


class EpisodeIndex:
    """Episode membership of a replay buffer's rows, inferred from ``obs[t] == next_obs[t-1]``.
    Rows are overwritten in insertion order, so an episode's newest row outlives its others: a
    row still labelled with an episode always finds that episode's newest row."""

    def __init__(self, capacity: int) -> None:
        self.capacity = int(capacity)
        self.episode = np.full(self.capacity, -1, np.int64)
        # newest row of each live episode, at episode % capacity (at most capacity live ones)
        self._last = np.full(self.capacity, -1, np.int64)
        self._n_episodes = 0
        self._prev_next: np.ndarray | None = None

    def add(self, row: int, obs: np.ndarray, next_obs: np.ndarray) -> None:
        if self._prev_next is None or not np.array_equal(obs, self._prev_next):
            self._n_episodes += 1
        ep = self._n_episodes - 1
        self.episode[row] = ep
        self._last[ep % self.capacity] = row
        self._prev_next = np.array(next_obs, copy=True)

    def future(self, rows: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """A row at or after each of ``rows`` in its episode (uniform), or -1 for a row with no
        episode."""
        rows = np.asarray(rows, np.int64)
        ep = self.episode[rows]
        last = self._last[ep % self.capacity]
        span = (last - rows) % self.capacity
        out = (rows + (rng.random(len(rows)) * (span + 1)).astype(np.int64)) % self.capacity
        return np.where(ep >= 0, out, -1)
