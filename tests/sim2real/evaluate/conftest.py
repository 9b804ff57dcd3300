"""A scripted reaching policy (inverse kinematics) to check what evaluation measures."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from hardware.spec import load_spec
from sim2real.export.policy import Policy, PolicyMeta

torch.set_num_threads(1)


class IKPolicy(Policy):
    """Moves each joint toward the IK solution of the observed goal: a known-good controller,
    so evaluation must report a high success; ``gain=0`` never moves and must report ~0."""

    def __init__(self, meta: PolicyMeta, gain: float = 0.5) -> None:
        self.meta = meta
        self.gain = gain
        self.spec = load_spec()

    def _act(self, batch: np.ndarray) -> np.ndarray:
        out = np.zeros((len(batch), 3), dtype=np.float32)
        for i, obs in enumerate(batch):
            q, goal = obs[0:3], obs[6:9]
            q_goal = self.spec.inverse_kinematics(goal)
            if q_goal is not None:
                step = self.gain * (q_goal - q) / self.meta.max_delta_rad
                out[i] = np.clip(step, -1.0, 1.0)
        return out


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A PPO run of a few hundred steps: a real run dir whose metadata the tests reuse."""
    from sim2real.train import resolve_config, train

    run = tmp_path_factory.mktemp("eval") / "ppo"
    cfg = resolve_config(
        "reach",
        "ppo",
        run,
        steps=256,
        progress=False,
        overrides=["n_envs=2", "n_steps=64", "batch_size=64", "n_epochs=1"],
    )
    train(cfg)
    return run


@pytest.fixture
def ik_target(tiny_run: Path) -> Any:
    """An EvalTarget for the run's env, driven by the IK policy instead of the network."""
    from sim2real.evaluate import EvalTarget

    target = EvalTarget.load(tiny_run)
    return replace(target, policy=IKPolicy(target.policy.meta))
