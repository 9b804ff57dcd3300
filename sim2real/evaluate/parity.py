"""Parity of an exported policy with the torch policy it came from, on real observations."""

from __future__ import annotations

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


def parity_check(
    run_dir: str | Path, exported: str | Path, n: int = 1000, tolerance: float = PARITY_TOLERANCE
) -> float:
    diff = max_action_diff(run_dir, exported, sample_observations(run_dir, n))
    if not diff <= tolerance:
        raise PolicyError(
            f"exported policy {str(exported)!r} differs from the torch policy by {diff:.3g} "
            f"> {tolerance:g} over {n} observations"
        )
    return diff
