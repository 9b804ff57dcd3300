"""Distillation on the arm's pixel pick from a shipped state policy (``pick_ppo``): the pixel env
reports the state env's observation at its privileged state's tail, the teacher acts on it as the
shipped policy acts on the state env, refuses an env it would mislabel, and a preset run trains.

Runs use small frames and few steps: the tests exercise the method, not its figures (those are
``bench/pick_teacher.py``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import sim2real.envs as envs
from sim2real.envs.base import privileged_true_size
from sim2real.errors import ConfigError
from sim2real.export import load_policy
from sim2real.train import RunDir, resolve_config, train
from sim2real.train.distill import TEACHERS, Distill, get_teacher
from sim2real.train.factory import build_vec_env, transpose_images

PICK = {"image_size": 48, "safety_filter": True}  # pick-ppo's env kwargs (its card)


@pytest.mark.parametrize("dr", ["none", "default"])
def test_the_privileged_tail_is_the_state_envs_observation(dr: str) -> None:
    """Same seed, same actions: the pixel env senses as the state env does, draw for draw
    (sensor noise, delay and occlusion under ``default``), so the tail is equal bit for bit."""
    state = envs.make("pick", dr=dr, safety_filter=True)
    pixels = envs.make("pick-pixels", dr=dr, proprio=["joint_pos"], **PICK)
    u: Any = pixels.unwrapped
    start = privileged_true_size(u.spec_arm, u.task)
    assert u.privileged_space.shape == (start + u.builder.size,)
    rng = np.random.default_rng(0)
    try:
        s_obs, _ = state.reset(seed=11)
        p_obs, info = pixels.reset(seed=11)
        for _ in range(20):
            tail = info["privileged_state"][start:]
            np.testing.assert_array_equal(tail, s_obs)
            np.testing.assert_array_equal(p_obs["proprio"], s_obs[:4])  # joint_pos
            action = rng.uniform(-1.0, 1.0, 4).astype(np.float32)
            s_obs, *_ = state.step(action)
            p_obs, _, _, _, info = pixels.step(action)
    finally:
        state.close()
        pixels.close()


def test_the_teacher_is_the_shipped_policy_on_that_observation() -> None:
    assert {"pick_ppo", "pick_ddpg", "pick_servo"} <= set(TEACHERS)
    env = envs.make("pick-pixels", dr="default", **PICK)
    u: Any = env.unwrapped
    policy = load_policy("pick-ppo")
    teacher = get_teacher("pick_ppo", u.decoder)
    assert teacher.continuous and teacher.n_inputs == 6 and teacher.check_env is not None
    teacher.check_env(env.spec.kwargs if env.spec is not None else {})
    start = privileged_true_size(u.spec_arm, u.task)
    try:
        _, info = env.reset(seed=3)
        for _ in range(5):
            priv = info["privileged_state"]
            action = teacher.action(priv)
            assert action.dtype == np.float32 and np.all(np.abs(action) <= 1.0)
            np.testing.assert_array_equal(action, np.clip(policy(priv[start:]), -1.0, 1.0))
            tool, cube = u.ee_position(), u.task.cube_position(u)
            np.testing.assert_allclose(teacher.inputs(priv), 10 * np.r_[tool, cube], rtol=1e-5)
            _, _, _, _, info = env.step(action)
    finally:
        env.close()


def test_the_teacher_refuses_an_env_it_would_mislabel() -> None:
    # the safety filter off: the policy was trained through it
    env = envs.make("pick-pixels", dr="none", image_size=48)
    teacher = get_teacher("pick_ppo", env.unwrapped.decoder)  # type: ignore[attr-defined]
    assert teacher.check_env is not None
    with pytest.raises(ConfigError, match="trained with safety_filter=True; the env has safety"):
        teacher.check_env(env.spec.kwargs if env.spec is not None else {})
    with pytest.raises(ConfigError, match="needs a privileged state of 55 values .* got 47"):
        teacher.action(np.zeros(47, dtype=np.float32))
    env.close()
    # another task: reach has no gripper action
    reach = envs.make("reach-pixels", dr="none", image_size=48)
    with pytest.raises(ConfigError, match="acts in 4 dimensions; the env's action has 3"):
        get_teacher("pick_ppo", reach.unwrapped.decoder)  # type: ignore[attr-defined]
    reach.close()
    # and Distill checks before it trains
    venv = transpose_images(
        build_vec_env("pick-pixels", {"dr": "none", "image_size": 48}, [0], privileged=True)
    )
    try:
        with pytest.raises(ConfigError, match="safety_filter=True"):
            Distill("MultiInputPolicy", venv, teacher="pick_ppo", device="cpu")
    finally:
        venv.close()


def test_the_preset_distills_pick_pixels_and_logs_the_teachers_agreement(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    cfg = resolve_config(
        "pick-pixels",
        "distill",
        run_dir,
        dr="none",
        steps=128,
        preset="distill_pick_pixels",
        progress=False,
        overrides=[
            "n_envs=2",
            "n_steps=16",
            "gradient_steps=2",
            "batch_size=16",
            "env_kwargs.image_size=48",
            "log_interval=1",
            "checkpoint_every=10000",
        ],
    )
    assert cfg.env_kwargs["safety_filter"] is True and cfg.hyperparams["teacher"] == "pick_servo"
    train(cfg)
    rows = [json.loads(line) for line in RunDir(run_dir).metrics_path.read_text().splitlines()]
    logged = [r for r in rows if "train/teacher_agreement" in r]
    assert len(logged) >= 3
    assert all(0.0 <= r["train/teacher_agreement"] <= 1.0 for r in logged)
    assert all(r["train/action_error"] >= 0.0 for r in logged)
    assert RunDir(run_dir).model_path.exists()
