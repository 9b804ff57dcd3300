"""Evaluate any policy (run dir, ``.onnx``, ``.npz``) on held-out seeds under a chosen DR preset.

Training env *i* of segment *k* resets first with a seed below ``EVAL_SEED_BASE`` (recorded in
``config.json``); evaluation episodes reset with ``EVAL_SEED_BASE + offset + j``. The two sets are
checked to be disjoint, so the reported success is on episodes the policy never trained on.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

from sim2real.evaluate.rollout import EvalResult, run_episodes
from sim2real.held_out import MAX_EPISODES, EvalTarget, held_out_placements
from sim2real.randomization import DRConfig

__all__ = ["MAX_EPISODES", "EvalTarget", "evaluate", "held_out_placements"]


def evaluate(
    target: EvalTarget,
    episodes: int = 200,
    dr: str | None = None,
    seed_offset: int = 0,
    n_parallel: int = 16,
    progress: bool = False,
) -> dict[str, Any]:
    """The figures ``sim2real evaluate --json`` prints (a bar over episodes on a terminal)."""
    from sim2real.progress import progress_bar

    seeds = target.held_out_seeds(episodes, seed_offset)
    dr_config = target.dr(dr)
    t0 = time.perf_counter()
    with progress_bar(len(seeds), "evaluating", "episode", progress) as bar:
        result = run_episodes(
            target.policy,
            target.env_factory(dr_config),
            seeds,
            n_parallel,
            on_episode=lambda _: bar.update(1),
        )
    return report(target, dr_config, seeds, result, time.perf_counter() - t0)


def report(
    target: EvalTarget,
    dr: DRConfig,
    seeds: Sequence[int],
    result: EvalResult,
    wall_s: float,
) -> dict[str, Any]:
    m = target.policy.meta
    return {
        "policy": str(target.path),
        "env_id": target.env_id,
        "algo": m.algo,
        "trained_dr": target.train_dr.name,
        "dr": dr.name,
        "seeds": {"first": seeds[0], "count": len(seeds), "held_out": True},
        **result.summary(),
        "wall_s": round(wall_s, 3),
    }
