"""Evaluation on held-out seeds: success with Wilson intervals, transfer-gap sweeps, videos."""

from __future__ import annotations

from sim2real.evaluate.core import EvalTarget, evaluate
from sim2real.evaluate.rollout import Episode, EvalResult, run_episodes
from sim2real.evaluate.stats import mean_ci95, wilson_interval

__all__ = [
    "Episode",
    "EvalResult",
    "EvalTarget",
    "evaluate",
    "mean_ci95",
    "run_episodes",
    "wilson_interval",
]
