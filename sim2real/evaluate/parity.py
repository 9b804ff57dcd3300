"""Parity of an exported policy with the torch policy it came from, on real observations (for
a pixel policy, frames rendered by its env)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.export.policy import PolicyError, load_policy

PARITY_TOLERANCE = 1e-5  # largest allowed |action difference|, normalised action units


def sample_observations(run_dir: str | Path, n: int, seed: int = 0) -> Any:
    """``n`` observations from the run's env under its DR, driven by random actions."""
    from sim2real.evaluate.core import EvalTarget

    target = EvalTarget.load(run_dir)
    env = target.env_factory(target.train_dr)()
    try:
        obs, _ = env.reset(seed=seed)
        env.action_space.seed(seed)
        out = [obs]
        while len(out) < n:
            obs, _, term, trunc, _ = env.step(env.action_space.sample())
            out.append(obs if not (term or trunc) else env.reset()[0])
    finally:
        env.close()
    if isinstance(out[0], dict):
        return {k: np.stack([o[k] for o in out]) for k in out[0]}
    return np.stack(out)


def max_action_diff(run_dir: str | Path, exported: str | Path, obs: Any) -> float:
    ref = load_policy(run_dir)(obs)
    got = load_policy(exported)(obs)
    return float(np.max(np.abs(ref - got)))


@dataclass(frozen=True)
class ParityReport:
    """An exported policy against its torch policy, on the same observations. A discrete policy
    (an argmax over logits or Q-values) also reports on how many observations the actions differ
    and the largest score difference, which equal actions can hide."""

    observations: int
    max_abs_action_diff: float
    action_disagreements: int | None = None
    max_abs_score_diff: float | None = None

    def to_dict(self) -> dict[str, float | int]:
        return {k: v for k, v in asdict(self).items() if v is not None}


def parity_report(run_dir: str | Path, exported: str | Path, obs: Any) -> ParityReport:
    ref_policy, got_policy = load_policy(run_dir), load_policy(exported)
    ref, got = ref_policy(obs), got_policy(obs)
    n = len(ref)
    report = ParityReport(n, float(np.max(np.abs(ref - got))) if n else 0.0)
    ref_scores, got_scores = ref_policy.scores(obs), got_policy.scores(obs)
    if ref_scores is None or got_scores is None:
        return report
    return replace(
        report,
        action_disagreements=int(np.any(ref != got, axis=1).sum()),
        max_abs_score_diff=float(np.max(np.abs(ref_scores - got_scores))) if n else 0.0,
    )


def check_parity(
    run_dir: str | Path, exported: str | Path, n: int = 1000, tolerance: float = PARITY_TOLERANCE
) -> ParityReport:
    """The report on ``n`` observations from the run's env; a ``PolicyError`` if any action
    differs by more than ``tolerance`` (a discrete policy: if any action differs at all)."""
    report = parity_report(run_dir, exported, sample_observations(run_dir, n))
    if report.action_disagreements:
        raise PolicyError(
            f"exported policy {str(exported)!r} chooses another action than the torch policy on "
            f"{report.action_disagreements} of {n} observations (largest score difference "
            f"{report.max_abs_score_diff:.3g})"
        )
    if not report.max_abs_action_diff <= tolerance:
        raise PolicyError(
            f"exported policy {str(exported)!r} differs from the torch policy by "
            f"{report.max_abs_action_diff:.3g} > {tolerance:g} over {n} observations"
        )
    return report


def parity_check(
    run_dir: str | Path, exported: str | Path, n: int = 1000, tolerance: float = PARITY_TOLERANCE
) -> float:
    """``check_parity``'s largest action difference."""
    return check_parity(run_dir, exported, n, tolerance).max_abs_action_diff
