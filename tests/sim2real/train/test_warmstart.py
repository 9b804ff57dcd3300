"""A TD3 run started from a teacher's experience (``train.warmstart``): the shipped PPO pick
policy fills the replay buffer in the run's own MuJoCo envs, the actor learns to act as it does,
the critic learns its returns; bad warm starts are one-line errors that leave no run behind."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import sim2real.envs as envs
from sim2real.errors import ConfigError
from sim2real.export.formats import load_policy
from sim2real.train import resolve_config
from sim2real.train.rundir import RunDir

Train = Callable[..., Path]
TRANSITIONS = 2_000


def _warm(teacher: str = "pick-ppo", **extra: object) -> str:
    fields = {"teacher": teacher, "transitions": TRANSITIONS, "bc_epochs": 30}
    fields.update({"critic_updates": 300, **extra})
    return "warm_start=" + json.dumps(fields)


def test_a_warm_started_td3_acts_as_its_teacher_and_keeps_training(
    run_dir: Path, tiny: Train
) -> None:
    # the teacher's steps count against the budget; a few of the learner's own follow
    steps = TRANSITIONS + 8
    extra = [_warm(), "buffer_size=4000", "policy_kwargs.net_arch=[64, 64]"]
    tiny("td3", run_dir, env="pick", steps=steps, extra=extra)
    figures = json.loads((run_dir / "warm_start.json").read_text())
    assert figures["transitions"] == TRANSITIONS and figures["teacher_episodes"] >= 30
    assert figures["bc_final_mse"] < 0.5 * figures["bc_initial_mse"], figures
    assert figures["critic_final_loss"] < figures["critic_initial_loss"], figures
    status = RunDir(run_dir).read_status()
    assert status["finished"] and status["steps_done"] >= steps
    # the student acts as the teacher on observations neither saw in training
    student, teacher = load_policy(run_dir), load_policy("pick-ppo")
    env = envs.make("pick")
    try:
        obs = []
        for seed in range(4):
            o, _ = env.reset(seed=10_000 + seed)
            for _ in range(10):
                obs.append(o)
                o, *_ = env.step(np.clip(teacher(o), -1, 1))
        batch = np.stack(obs)
    finally:
        env.close()
    agree = np.mean((student(batch) - np.clip(teacher(batch), -1, 1)) ** 2)
    assert agree < 0.5 * figures["bc_initial_mse"], (agree, figures)


@pytest.mark.parametrize(
    ("algo", "override", "match"),
    [
        ("sac", _warm(), r"warm_start works with \['ddpg', 'td3'\].*not 'sac'"),
        ("td3", "warm_start={transitions: 10}", "warm_start needs a teacher"),
        ("td3", _warm(epochs=3), r"warm_start: unknown key\(s\) \['epochs'\]"),
        ("td3", _warm(noise_sigma=2), r"warm_start.noise_sigma must be in \[0, 1\], got 2"),
    ],
)
def test_bad_warm_starts_are_named(algo: str, override: str, match: str, run_dir: Path) -> None:
    with pytest.raises(ConfigError, match=match) as err:
        resolve_config("pick", algo, run_dir, overrides=[override])
    assert "\n" not in str(err.value)


def test_a_teacher_for_another_observation_leaves_no_run(run_dir: Path, tiny: Train) -> None:
    with pytest.raises(ConfigError, match=r"teacher 'reach-ppo'.*does not read this run") as err:
        tiny("td3", run_dir, env="pick", steps=400, extra=[_warm("reach-ppo")])
    assert "\n" not in str(err.value)
    assert not run_dir.exists()
