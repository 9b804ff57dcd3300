"""A policy's held-out episodes: the env it was trained on, rebuilt, and reset with evaluation
seeds no training env ever used.

Training env *i* of segment *k* resets first with a seed below ``EVAL_SEED_BASE`` (recorded in
``config.json``); evaluation episodes reset with ``EVAL_SEED_BASE + offset + j``. ``evaluate``
runs the policy on them; a deploy replays their objects (``--placements held-out``), so the
deploy runtime reads them from here, below both, not from ``evaluate``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from hardware.spec import ArmSpec
from sim2real.errors import ConfigError
from sim2real.export.policy import Policy, PolicyError, load_policy
from sim2real.randomization import DRConfig, load_preset

# Evaluation seeds start here; training seeds stay below (``train.config`` checks them).
EVAL_SEED_BASE = 1_000_000_000
MAX_EPISODES = 1_000_000


@dataclass(frozen=True)
class EvalTarget:
    """A loaded policy plus everything needed to rebuild the env it was trained on."""

    path: Path
    policy: Policy
    env_id: str
    env_kwargs: dict[str, Any]
    spec: ArmSpec
    train_dr: DRConfig
    training_seeds: tuple[int, ...]

    @classmethod
    def load(cls, path: str | Path) -> EvalTarget:
        policy = load_policy(path)
        m = policy.meta
        spec = ArmSpec.from_dict(dict(m.spec), source=f"{path}: spec")
        ranges = m.dr_ranges
        train_dr = DRConfig.from_dict(m.dr, ranges) if ranges else load_preset(m.dr)
        if spec.fingerprint() != m.spec_fingerprint:
            raise PolicyError(f"policy {str(path)!r}: embedded spec does not match its fingerprint")
        return cls(
            Path(path),
            policy,
            m.env_id,
            dict(m.env_kwargs),
            spec,
            train_dr,
            m.training_seeds,
        )

    def dr(self, name: str | None) -> DRConfig:
        """The training DR by default, else a preset name or YAML path."""
        return self.train_dr if name is None else load_preset(name)

    def env_factory(self, dr: DRConfig, **overrides: Any) -> Callable[[], gym.Env[Any, Any]]:
        import sim2real.envs as envs

        kwargs = {**self.env_kwargs, **overrides, "dr": dr, "spec": self.spec}
        meta = self.policy.meta

        def make() -> gym.Env[Any, Any]:
            env = envs.make(self.env_id, **kwargs)
            builder = getattr(env.unwrapped, "builder", None)
            if builder is not None:  # a stale policy must fail loudly, not act on shifted fields
                meta.check_layout([(f.name, f.stop - f.start) for f in builder.layout()])
            return env

        return make

    def held_out_seeds(self, episodes: int, offset: int = 0) -> list[int]:
        if not 1 <= episodes <= MAX_EPISODES:
            raise ConfigError(f"episodes {episodes} not in [1, {MAX_EPISODES}]")
        if offset < 0:
            raise ConfigError(f"seed offset {offset} must be >= 0")
        seeds = list(range(EVAL_SEED_BASE + offset, EVAL_SEED_BASE + offset + episodes))
        clash = set(seeds) & set(self.training_seeds)
        if clash:  # only possible for a hand-edited config
            raise ConfigError(f"evaluation seeds {sorted(clash)[:3]} were used in training")
        return seeds


def held_out_placements(
    target: EvalTarget, episodes: int, seed_offset: int = 0, dr: str = "none"
) -> list[dict[str, np.ndarray]]:
    """The objects of ``evaluate``'s held-out episodes (``Task.placement`` after each seeded
    reset; no policy runs). A deploy that replays them (``LoopConfig.placements``) is compared
    with ``evaluate`` on the same placements: at a pick policy's 30 % success, two independent
    100-episode samples cannot resolve a 0.9 ratio."""
    env = target.env_factory(target.dr(dr))()
    try:
        u = env.unwrapped
        if not hasattr(u, "task"):
            raise ConfigError(f"{target.env_id} has no task placements to replay")
        out = []
        for seed in target.held_out_seeds(episodes, seed_offset):
            env.reset(seed=seed)
            out.append(u.task.placement(u))
        return out
    finally:
        env.close()
