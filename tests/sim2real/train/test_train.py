"""Every algorithm trains on the real MuJoCo reach env, saves a complete run dir and reloads."""

from __future__ import annotations

import csv
import json
import pickle
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

import sim2real.envs as envs
from sim2real.errors import ConfigError
from sim2real.export import load_policy
from sim2real.train import ALGOS, RunDir, resume

STEPS = 400
REACH_OBS = envs.make("reach").observation_space.shape[0]  # type: ignore[index]
Train = Callable[..., Path]


# Distillation needs a teacher's privileged state, which reach does not report (see
# test_pixels_learning.py for it on the Kuka env).
@pytest.mark.parametrize("algo", sorted(a for a, s in ALGOS.items() if not s.needs_privileged))
def test_each_algorithm_trains_saves_and_reloads(algo: str, run_dir: Path, tiny: Train) -> None:
    tiny(algo, run_dir)
    rd = RunDir(run_dir)
    cfg = rd.read_config()
    assert cfg["algo"] == algo and cfg["env_id"] == "Sim2Real/Arm3Reach-v0"
    assert cfg["dr"] == "default" and cfg["training_seeds"] == [0, 1]
    assert cfg["spec_fingerprint"] and cfg["versions"]["stable-baselines3"]
    assert [f["name"] for f in cfg["obs_layout"]][:2] == ["joint_pos", "ee_pos"]
    status = rd.read_status()
    assert status["finished"] and status["steps_done"] >= STEPS
    assert rd.model_path.is_file() and rd.vecnormalize_path.is_file()
    assert [c.steps for c in rd.checkpoints()][-1] == status["steps_done"]
    assert len(list(rd.monitor_dir.glob("*.monitor.csv"))) == 2
    assert any(rd.tb_dir.iterdir())
    with rd.episodes_path.open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) >= 4 and all(r["length"] == "50" for r in rows)
    metrics = [json.loads(line) for line in rd.metrics_path.read_text().splitlines()]
    logged = set().union(*metrics)
    for key in ALGOS[algo].diagnostics:
        if key != "train/ent_coef" or algo == "sac":
            assert key in logged, f"{algo} did not log {key}"
    policy = load_policy(run_dir)
    env = envs.make("reach")
    obs, _ = env.reset(seed=5)
    action = policy(obs)
    assert action.shape == (3,) and np.all(np.abs(action) <= 1.0)
    batch = policy(np.stack([obs, obs]))
    np.testing.assert_allclose(batch[0], action, atol=1e-6)
    env.close()
    with rd.vecnormalize_path.open("rb") as fh:
        assert pickle.load(fh).obs_rms.count > STEPS // 2  # statistics really were collected
    if algo == "dqn":  # no-op + (±1, ±0.2) per joint, mapped back to the env's Box actions
        assert np.array(cfg["action_table"]).shape == (13, 3)
    if algo == "a2c":  # the norm SB3 clips and discards, recorded before clipping
        norms = [m["train/grad_norm"] for m in metrics if "train/grad_norm" in m]
        assert norms and all(n > 0 for n in norms)


def test_same_seed_same_actions_other_seed_differs(tmp_path: Path, tiny: Train) -> None:
    obs = np.random.default_rng(0).normal(size=(16, REACH_OBS)).astype(np.float32)
    acts = []
    for name, seed in (("a", 3), ("b", 3), ("c", 4)):
        tiny("td3", tmp_path / name, seed=seed, steps=200)
        acts.append(load_policy(tmp_path / name)(obs))
    np.testing.assert_array_equal(acts[0], acts[1])
    assert not np.allclose(acts[0], acts[2])


def test_resume_continues_the_step_count_with_fresh_seeds(run_dir: Path, tiny: Train) -> None:
    tiny("ppo", run_dir, steps=256)
    first = RunDir(run_dir).read_status()
    assert first["steps_done"] == 256
    result = resume(run_dir, steps=512, progress=False)
    assert result.steps_done == 512
    rd = RunDir(run_dir)
    status, cfg = rd.read_status(), rd.read_config()
    assert status["segments"] == 2 and status["finished"]
    assert cfg["steps"] == 512 and len(cfg["training_seeds"]) == 4  # 2 envs x 2 segments
    steps = [int(r["timesteps"]) for r in csv.DictReader(rd.episodes_path.open())]
    assert steps == sorted(steps) and steps[-1] > 256
    assert len(list(rd.monitor_dir.glob("seg1.*.monitor.csv"))) == 2


def test_her_on_the_goal_env_and_a_gripper_table_for_dqn(tmp_path: Path, tiny: Train) -> None:
    tiny("sac", tmp_path / "her", env="reach-goal", her=True, steps=200)
    cfg = RunDir(tmp_path / "her").read_config()
    assert cfg["train"]["her"] and cfg["policy"] == "MultiInputPolicy"
    assert cfg["obs_keys"] == ["achieved_goal", "desired_goal", "observation"]
    policy = load_policy(tmp_path / "her")
    env = envs.make("reach-goal")
    obs, _ = env.reset(seed=1)
    assert policy(obs).shape == (3,)
    env.close()
    tiny("dqn", tmp_path / "pick", env="pick", steps=150)
    table = np.array(RunDir(tmp_path / "pick").read_config()["action_table"])
    assert table.shape == (26, 4) and set(table[:, 3]) == {-1.0, 1.0}


def test_pixel_env_trains_a_cnn_policy(run_dir: Path, tiny: Train) -> None:
    tiny(
        "ppo",
        run_dir,
        env="reach-pixels",
        steps=64,
        extra=["n_steps=32", "batch_size=32", "n_epochs=1", "env_kwargs.image_size=48"],
    )
    cfg = RunDir(run_dir).read_config()
    assert cfg["policy"] == "CnnPolicy" and cfg["obs_shape"] == [48, 48, 3]
    policy = load_policy(run_dir)
    env = envs.make("reach-pixels", image_size=48)
    obs, _ = env.reset(seed=0)
    assert policy(obs).shape == (3,)
    env.close()


def test_subprocess_workers_train_the_same_policy_as_in_process_envs(
    tmp_path: Path, tiny: Train
) -> None:
    obs = np.random.default_rng(1).normal(size=(8, REACH_OBS)).astype(np.float32)
    tiny("ppo", tmp_path / "dummy", steps=128)
    tiny("ppo", tmp_path / "subproc", steps=128, extra=["vec_env=subproc"])
    cfg = RunDir(tmp_path / "subproc").read_config()
    assert cfg["train"]["vec_env"] == "subproc" and cfg["train"]["n_envs"] == 2
    np.testing.assert_allclose(
        load_policy(tmp_path / "dummy")(obs), load_policy(tmp_path / "subproc")(obs), atol=1e-6
    )


def test_the_torch_device_is_the_cpu_unless_set_and_a_bad_one_is_named(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from sim2real.train.runner import TORCH_DEVICE_ENV, torch_device

    monkeypatch.delenv(TORCH_DEVICE_ENV, raising=False)
    assert torch_device() == "cpu"
    monkeypatch.setenv(TORCH_DEVICE_ENV, "tpu9")
    with pytest.raises(ConfigError, match="SIM2REAL_TORCH_DEVICE='tpu9' is not a torch device"):
        torch_device()
    if not torch.cuda.is_available():
        monkeypatch.setenv(TORCH_DEVICE_ENV, "cuda")
        with pytest.raises(ConfigError, match="torch sees no CUDA device"):
            torch_device()
