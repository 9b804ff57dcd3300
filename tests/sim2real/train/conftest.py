"""Tiny training budgets: enough steps for episodes to end and gradient updates to happen."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
import torch

torch.set_num_threads(1)

# Per algorithm: overrides that make a few hundred steps exercise the whole update path.
TINY: dict[str, list[str]] = {
    "ppo": ["n_envs=2", "n_steps=64", "batch_size=64", "n_epochs=2"],
    "a2c": ["n_envs=2", "n_steps=16"],
    "ddpg": [
        "n_envs=2",
        "learning_starts=100",
        "buffer_size=2000",
        "batch_size=64",
        "gradient_steps=1",
    ],
    "td3": [
        "n_envs=2",
        "learning_starts=100",
        "buffer_size=2000",
        "batch_size=64",
        "gradient_steps=1",
    ],
    "sac": [
        "n_envs=2",
        "learning_starts=100",
        "buffer_size=2000",
        "batch_size=64",
        "gradient_steps=1",
    ],
    "dqn": [
        "n_envs=2",
        "learning_starts=100",
        "buffer_size=2000",
        "batch_size=64",
        "gradient_steps=1",
    ],
}
COMMON = ["log_interval=1", "policy_kwargs.net_arch=[32, 32]"]


def tiny_overrides(algo: str) -> list[str]:
    return [*TINY[algo], *COMMON]


def train_tiny(
    algo: str,
    run_dir: Path,
    *,
    env: str = "reach",
    seed: int = 0,
    steps: int = 400,
    her: bool = False,
    extra: list[str] | None = None,
) -> Path:
    """Train ``algo`` for ``steps`` with tiny networks and buffers; returns the run dir."""
    from sim2real.train import resolve_config, train

    cfg = resolve_config(
        env,
        algo,
        run_dir,
        seed=seed,
        steps=steps,
        her=her,
        progress=False,
        overrides=[*tiny_overrides(algo), "checkpoint_every=200", *(extra or [])],
    )
    train(cfg)
    return run_dir


@pytest.fixture
def tiny() -> Callable[..., Path]:
    return train_tiny


@pytest.fixture
def run_dir(tmp_path: Path) -> Path:
    return tmp_path / "run"
