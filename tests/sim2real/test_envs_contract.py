"""Every registered id: Gymnasium and SB3 env checkers, same-seed determinism, obs in space."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sim2real.envs as envs
from sim2real.randomization.config import CATEGORY_NAMES

IDS = envs.env_ids()


def _rollout(env_id: str, seed: int, steps: int = 30) -> list[Any]:
    env = gym.make(env_id)
    try:
        obs, _ = env.reset(seed=seed)
        env.action_space.seed(seed)
        trace = [obs]
        for _ in range(steps):
            obs, reward, term, trunc, info = env.step(env.action_space.sample())
            trace += [obs, reward, term, trunc, info["is_success"]]
        return trace
    finally:
        env.close()


def _flatten(x: Any) -> list[np.ndarray]:
    if isinstance(x, dict):
        return [np.asarray(x[k]) for k in sorted(x)]
    return [np.asarray(x)]


@pytest.mark.filterwarnings("ignore:.*Box observation space m.* value is.*infinity")
@pytest.mark.parametrize("env_id", IDS)
def test_gymnasium_and_sb3_checkers_pass(env_id: str) -> None:
    env = gym.make(env_id)
    try:
        gym_check_env(env.unwrapped, skip_render_check=True)
        sb3_check_env(env.unwrapped, warn=False)
    finally:
        env.close()


@pytest.mark.parametrize("env_id", IDS)
def test_same_seed_gives_identical_rollouts_and_other_seed_differs(env_id: str) -> None:
    a, b, c = _rollout(env_id, 3), _rollout(env_id, 3), _rollout(env_id, 4)
    for x, y in zip(a, b, strict=True):
        for u, v in zip(_flatten(x), _flatten(y), strict=True):
            np.testing.assert_array_equal(u, v)
    assert any(
        not np.array_equal(u, v)
        for x, y in zip(a, c, strict=True)
        for u, v in zip(_flatten(x), _flatten(y), strict=True)
    )


@pytest.mark.parametrize("env_id", IDS)
def test_observations_stay_inside_the_declared_space(env_id: str) -> None:
    env = gym.make(env_id)
    try:
        obs, info = env.reset(seed=0)
        assert "dr" in info and set(info["dr"]) == set(CATEGORY_NAMES)
        for _ in range(60):
            assert env.observation_space.contains(obs)
            obs, _, term, trunc, info = env.step(env.action_space.sample())
            assert isinstance(info["is_success"], bool)
            if term or trunc:
                obs, _ = env.reset()
    finally:
        env.close()


def test_episode_is_50_steps_at_20_hz_and_exposes_mujoco_env_attributes() -> None:
    env = gym.make("Sim2Real/Arm3Reach-v0")
    u = env.unwrapped
    assert u.frame_skip * u.model.opt.timestep == pytest.approx(0.05)
    assert u.data.time == 0.0
    env.reset(seed=0)
    n = 0
    trunc = False
    while not trunc:
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        assert not term
        n += 1
    assert n == 50
    assert u.data.time == pytest.approx(50 * 0.05)
    env.close()


def test_goal_env_compute_reward_matches_step_reward() -> None:
    env = gym.make("Sim2Real/Arm3ReachGoal-v0", dr="none")
    u = env.unwrapped
    obs, _ = env.reset(seed=5)
    for _ in range(10):
        obs, reward, _, _, info = env.step(env.action_space.sample())
    # With DR off the sensed goals are the true ones, so HER's recomputation is exact.
    again = u.compute_reward(obs["achieved_goal"][None], obs["desired_goal"][None], [info])
    assert again[0] == pytest.approx(reward, abs=1e-6)
    batch = u.compute_reward(np.zeros((4, 3)), np.full((4, 3), 0.001), None)
    assert batch.shape == (4,) and np.all(batch == 0.0)  # within 1 cm: sparse reward 0


def test_pixel_env_renders_the_scene_at_84_and_48() -> None:
    for size in (84, 48):
        env = gym.make("Sim2Real/Arm3ReachPixels-v0", image_size=size, dr="none")
        obs, _ = env.reset(seed=0)
        assert obs.shape == (size, size, 3) and obs.dtype == np.uint8
        assert obs.std() > 10  # not a blank frame
        env.close()


def test_short_names_and_unknown_ids() -> None:
    assert envs.resolve_env_id("reach") == "Sim2Real/Arm3Reach-v0"
    assert envs.resolve_env_id("Arm3Pick") == "Sim2Real/Arm3Pick-v0"
    with pytest.raises(KeyError, match="unknown env 'Arm3Fly'"):
        envs.resolve_env_id("Arm3Fly")


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"dr": "wild"}, "unknown DR preset 'wild'; valid: default, none, shifted, strong"),
        ({"obs_mode": "depth"}, "unknown obs_mode 'depth'"),
        ({"reward": "huber"}, "unknown reward 'huber'"),
        ({"camera": "cam_top"}, "unknown camera 'cam_top'"),
        ({"control_hz": 0.1}, "control_hz 0.1"),
    ],
)
def test_bad_env_kwargs_get_a_one_line_error(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(Exception, match=message) as info:
        gym.make("Sim2Real/Arm3Reach-v0", **kwargs)
    assert "\n" not in str(info.value)
