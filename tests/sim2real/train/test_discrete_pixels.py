"""Envs with their own ``Discrete`` actions and pixel observations, through the whole trainer.

``Sim2Real/KukaGraspFast-v0`` (7 discrete actions, 48x48 uint8 RGB) trains as-is with dqn, ppo
and a2c: no joint-delta table, a CNN policy, no observation normalisation, and the run dir
reloads, resumes, evaluates and gives ``compare`` its diagnostics.
"""

from __future__ import annotations

import csv
import json
import pickle
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import sim2real.envs as envs
from sim2real.compare.jobs import curves
from sim2real.errors import ConfigError, RunDirError
from sim2real.evaluate import EvalTarget, evaluate
from sim2real.export import load_policy
from sim2real.train import ALGOS, RunDir, resolve_config, resume
from sim2real.train.factory import obs_normalization

Train = Callable[..., Path]
KUKA = "Sim2Real/KukaGraspFast-v0"
STEPS = 300


@pytest.mark.parametrize("algo", ["dqn", "ppo"])
def test_discrete_pixel_env_trains_saves_reloads_and_evaluates(
    algo: str, run_dir: Path, tiny: Train
) -> None:
    tiny(algo, run_dir, env="kuka-fast", steps=STEPS)
    rd = RunDir(run_dir)
    cfg = rd.read_config()
    assert cfg["env_id"] == KUKA and cfg["policy"] == "CnnPolicy"
    assert cfg["action_table"] is None  # the env's own 7 actions, no DiscreteDeltaActions
    assert cfg["action_dim"] == 1 and cfg["n_actions"] == 7
    assert cfg["obs_shape"] == [48, 48, 3] and cfg["vecnormalize"] is None
    assert rd.read_status()["finished"] and rd.model_path.is_file()
    assert not rd.vecnormalize_path.exists()
    assert all(c.vecnormalize is None for c in rd.checkpoints())
    metrics = [json.loads(line) for line in rd.metrics_path.read_text().splitlines()]
    logged = set().union(*metrics)
    assert set(ALGOS[algo].diagnostics) <= logged

    policy = load_policy(run_dir)
    assert policy.vecnormalize is None  # type: ignore[attr-defined]
    env = envs.make(KUKA)
    obs, _ = env.reset(seed=3)
    action = policy(obs)
    assert action.shape == (1,) and env.action_space.contains(int(action[0]))
    np.testing.assert_array_equal(policy(np.stack([obs, obs]))[0], action)
    env.close()

    ev = evaluate(EvalTarget.load(run_dir), episodes=4)
    assert ev["episodes"] == 4 and ev["seeds"]["held_out"]
    assert 1 <= ev["mean_episode_length"] <= 12  # the descent ends every episode by step 12

    got = curves(run_dir, algo, STEPS, n_bins=5)
    for key, values in got["diagnostics"].items():
        assert any(v is not None for v in values), f"{algo}: no {key} for compare"
    assert got["train_episodes"] >= 2 * (STEPS // 2 // 12) - 2


def test_dqn_pixel_run_resumes_from_its_replay_buffer(run_dir: Path, tiny: Train) -> None:
    # The dqn_kuka_fast preset skips the replay file (0.7 GB at its buffer size); a tiny one is kept.
    tiny("dqn", run_dir, env="kuka-fast", steps=200, extra=["save_replay=true"])
    ckpt = RunDir(run_dir).latest_checkpoint()
    assert ckpt is not None and ckpt.replay is not None
    result = resume(run_dir, steps=300, progress=False)
    assert result.steps_done >= 300 and RunDir(run_dir).read_status()["segments"] == 2


def test_reward_normalisation_on_pixels_keeps_the_frames_raw(run_dir: Path, tiny: Train) -> None:
    """A VecNormalize for rewards alone: the replay buffer stores uint8 channel-first frames."""
    tiny(
        "dqn",
        run_dir,
        env="kuka-fast",
        steps=200,
        extra=["normalize_reward=true", "save_replay=true"],
    )
    rd = RunDir(run_dir)
    assert rd.read_config()["vecnormalize"] == {
        "norm_obs": False,
        "norm_obs_keys": None,
        "norm_reward": True,
    }
    with rd.vecnormalize_path.open("rb") as fh:
        vn = pickle.load(fh)
    assert not vn.norm_obs and vn.norm_reward and vn.ret_rms.count > 100
    ckpt = rd.latest_checkpoint()
    assert ckpt is not None and ckpt.replay is not None
    with ckpt.replay.open("rb") as fh:
        buffer = pickle.load(fh)
    assert buffer.observations.dtype == np.uint8
    assert buffer.observations.shape[-3:] == (3, 48, 48)
    assert 0 < buffer.observations.max() <= 255
    assert evaluate(EvalTarget.load(run_dir), episodes=2)["episodes"] == 2


@pytest.mark.parametrize("algo", ["ddpg", "td3", "sac"])
def test_continuous_only_algos_refuse_a_discrete_env(algo: str, run_dir: Path) -> None:
    with pytest.raises(ConfigError) as err:
        resolve_config("kuka-fast", algo, run_dir)
    msg = str(err.value)
    assert "\n" not in msg and algo in msg and KUKA in msg
    assert msg.endswith("use one of: a2c, distill, dqn, ppo")
    assert not run_dir.exists()
    resolve_config("kuka-fast-cont", algo, run_dir)  # the continuous twin takes them


def test_obs_normalization_leaves_every_image_out() -> None:
    image = gym.spaces.Box(0, 255, (48, 48, 3), np.uint8)
    state = gym.spaces.Box(-np.inf, np.inf, (15,), np.float32)
    assert obs_normalization(image, True) == (False, None)
    assert obs_normalization(state, True) == (True, None)
    assert obs_normalization(state, False) == (False, None)
    mixed = gym.spaces.Dict({"pixels": image, "joints": state})
    assert obs_normalization(mixed, True) == (True, ["joints"])
    assert obs_normalization(gym.spaces.Dict({"a": image, "b": image}), True) == (False, None)
    assert obs_normalization(gym.spaces.Dict({"a": state, "b": state}), True) == (True, None)


def test_env_kwargs_episode_length_reaches_the_env(run_dir: Path, tiny: Train) -> None:
    """``max_episode_steps`` longer than the default 50: episodes last that long in training."""
    tiny("ppo", run_dir, steps=256, extra=["env_kwargs.max_episode_steps=60"])
    with RunDir(run_dir).episodes_path.open() as fh:
        lengths = {int(r["length"]) for r in csv.DictReader(fh)}
    assert lengths == {60}


def test_a_normalised_run_without_its_statistics_is_refused(run_dir: Path, tiny: Train) -> None:
    """State runs still normalise; their policy must not silently run on raw observations."""
    tiny("ppo", run_dir, steps=128)
    rd = RunDir(run_dir)
    assert rd.read_config()["vecnormalize"]["norm_obs"] and rd.vecnormalize_path.is_file()
    rd.vecnormalize_path.unlink()
    with pytest.raises(RunDirError, match="vecnormalize.pkl is missing"):
        load_policy(run_dir)
