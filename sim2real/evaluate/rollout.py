"""Deterministic rollouts of a ``Policy`` on held-out seeds, batched over a few envs.

Every episode resets with its own seed, so the result depends on the policy and the seeds only,
not on the batch size. Policies are called on the stacked observations of the live envs: one
forward pass per control step instead of one per env.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from sim2real.evaluate.stats import wilson_interval


@dataclass(frozen=True)
class Episode:
    seed: int
    success: bool
    final_distance_m: float
    length: int
    ret: float


@dataclass(frozen=True)
class Transition:
    """One env step as a recorder sees it: the observation the action was chosen on."""

    slot: int
    env: gym.Env[Any, Any]
    obs: Any
    action: np.ndarray
    reward: float
    info: dict[str, Any]
    done: bool


@dataclass(frozen=True)
class EvalResult:
    episodes: tuple[Episode, ...]

    @property
    def n(self) -> int:
        return len(self.episodes)

    @property
    def successes(self) -> int:
        return sum(e.success for e in self.episodes)

    @property
    def success_rate(self) -> float:
        return self.successes / self.n if self.n else math.nan

    def summary(self) -> dict[str, Any]:
        d = np.array([e.final_distance_m for e in self.episodes])
        lo, hi = wilson_interval(self.successes, self.n)
        return {
            "episodes": self.n,
            "successes": self.successes,
            "success_rate": self.success_rate,
            "success_rate_wilson95": [lo, hi],
            "mean_final_distance_m": float(d.mean()) if self.n else math.nan,
            "median_final_distance_m": float(np.median(d)) if self.n else math.nan,
            "mean_episode_length": float(np.mean([e.length for e in self.episodes])),
            "mean_return": float(np.mean([e.ret for e in self.episodes])),
        }

    def to_rows(self) -> list[dict[str, Any]]:
        return [asdict(e) for e in self.episodes]


def _stack(obs: Sequence[Any]) -> Any:
    if isinstance(obs[0], dict):
        return {k: np.stack([o[k] for o in obs]) for k in obs[0]}
    return np.stack(obs)


def run_episodes(
    policy: Callable[[Any], np.ndarray],
    make_env: Callable[[], gym.Env[Any, Any]],
    seeds: Sequence[int],
    n_parallel: int = 16,
    on_step: Callable[[int, gym.Env[Any, Any]], None] | None = None,
    on_transition: Callable[[Transition], None] | None = None,
    on_episode: Callable[[Episode], None] | None = None,
) -> EvalResult:
    """One episode per seed; ``on_step(slot, env)`` sees every step (video, viewer),
    ``on_transition`` every (obs, action, reward, info) step and ``on_episode`` every finished
    episode (dataset recording, progress)."""
    n_parallel = max(1, min(n_parallel, len(seeds)))
    envs = [make_env() for _ in range(n_parallel)]
    queue = list(seeds)
    live: dict[int, dict[str, Any]] = {}
    obs: dict[int, Any] = {}
    results: dict[int, Episode] = {}
    order = {s: i for i, s in enumerate(seeds)}

    def start(slot: int) -> None:
        seed = queue.pop(0)
        obs[slot], _ = envs[slot].reset(seed=seed)
        live[slot] = {"seed": seed, "ret": 0.0, "len": 0}
        if on_step is not None:
            on_step(slot, envs[slot])

    try:
        for slot in range(n_parallel):
            start(slot)
        while live:
            slots = sorted(live)
            actions = policy(_stack([obs[s] for s in slots]))
            for slot, action in zip(slots, actions, strict=True):
                env = envs[slot]
                before = obs[slot]
                obs[slot], reward, term, trunc, info = env.step(action)
                if on_transition is not None:
                    on_transition(
                        Transition(slot, env, before, action, float(reward), info, term or trunc)
                    )
                ep = live[slot]
                ep["ret"] += float(reward)
                ep["len"] += 1
                if on_step is not None:
                    on_step(slot, env)
                if term or trunc:
                    done = results[order[ep["seed"]]] = Episode(
                        seed=ep["seed"],
                        success=bool(info["is_success"]),
                        final_distance_m=float(info.get("distance_m", math.nan)),
                        length=ep["len"],
                        ret=ep["ret"],
                    )
                    if on_episode is not None:
                        on_episode(done)
                    del live[slot]
                    if queue:
                        start(slot)
    finally:
        for env in envs:
            env.close()
    return EvalResult(tuple(results[i] for i in range(len(seeds))))
