"""A short SB3 run on robosuite Lift: trains, saves, loads and evaluates through the same env.

This is what the training CLI relies on: a flat Box observation, a [-1, 1] Box action,
``info["is_success"]`` on every step and truncation (not termination) at the episode length.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.monitor import Monitor

import sim2real.envs  # noqa: F401  (registers the ids)


def test_short_sac_run_on_lift_saves_loads_and_evaluates(tmp_path: Path) -> None:
    torch.set_num_threads(1)
    env = Monitor(gym.make("Sim2Real/RobosuiteLift-v0", dr="default", max_episode_steps=40))
    model = SAC(
        "MlpPolicy",
        env,
        learning_starts=100,
        batch_size=64,
        buffer_size=5_000,
        policy_kwargs={"net_arch": [64, 64]},
        seed=0,
        device="cpu",
    )
    model.learn(total_timesteps=240)
    assert model.num_timesteps == 240
    assert env.get_episode_rewards() and len(env.get_episode_rewards()) == 6  # 240 / 40
    path = tmp_path / "lift_sac.zip"
    model.save(path)
    env.close()

    eval_env = gym.make("Sim2Real/RobosuiteLift-v0", dr="default", max_episode_steps=40)
    loaded = SAC.load(path, device="cpu")
    obs, _ = eval_env.reset(seed=123)
    a_saved, _ = model.predict(obs, deterministic=True)
    a_loaded, _ = loaded.predict(obs, deterministic=True)
    np.testing.assert_allclose(a_loaded, a_saved, rtol=1e-6)  # the same policy came back
    try:
        for episode in range(2):
            obs, _ = eval_env.reset(seed=1000 + episode)
            steps, ret, trunc, info = 0, 0.0, False, {}
            while not trunc:
                action, _ = loaded.predict(obs, deterministic=True)
                assert eval_env.action_space.contains(action)
                obs, reward, term, trunc, info = eval_env.step(action)
                assert not term
                ret += reward
                steps += 1
            assert steps == 40
            assert isinstance(info["is_success"], bool) and np.isfinite(ret)
            assert 0.0 <= ret <= 40.0  # robosuite's shaped Lift reward lies in [0, 1] per step
    finally:
        eval_env.close()


# slow (CI runs it after the main suite): six robosuite worker processes start, ~16 s of a core;
# the fast suite keeps robosuite training in process (above) and the subprocess runner on MuJoCo
# (tests/sim2real/train/test_train.py)
@pytest.mark.slow
def test_shipped_reach_preset_trains_in_worker_processes_resumes_and_evaluates(
    tmp_path: Path,
) -> None:
    """The robosuite presets step their envs in subprocesses (bench/robosuite_vec_env.py): the
    runner's whole path, resume included, works with robosuite in the workers."""
    from sim2real.evaluate import EvalTarget, evaluate
    from sim2real.train import resolve_config, resume, train

    run = tmp_path / "run"
    cfg = resolve_config(
        "robosuite-reach",
        "ppo",
        run,
        steps=128,
        progress=False,
        overrides=["n_envs=2", "n_steps=64", "batch_size=64", "n_epochs=1"],
    )
    assert cfg.preset == "ppo_robosuite_reach" and cfg.vec_env == "subproc"
    assert train(cfg).steps_done == 128
    assert resume(run, steps=256, progress=False).steps_done == 256
    result = evaluate(EvalTarget.load(run), episodes=2, dr="none", n_parallel=2)
    assert result["episodes"] == 2 and result["env_id"] == "Sim2Real/RobosuiteReach-v0"
