"""Task logic on scripted action sequences with real physics: what succeeds and what fails."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import sim2real.envs  # noqa: F401
from sim2real.envs.base import Arm3Env


def _drive_to(env: gym.Env, p: np.ndarray, steps: int, grip: float | None = None) -> tuple:
    """A scripted IK controller through the env's own action interface."""
    u = env.unwrapped
    assert isinstance(u, Arm3Env)
    q_des = u.spec_arm.inverse_kinematics(p)
    assert q_des is not None, p
    out: tuple = ()
    for _ in range(steps):
        a = np.zeros(env.action_space.shape, dtype=np.float32)
        a[:3] = np.clip((q_des - u._targets[:3]) / u.decoder.max_delta_rad, -1, 1)
        if grip is not None:
            a[3] = grip
        out = env.step(a)
    return out


@pytest.mark.parametrize("dr", ["none", "default"])
def test_scripted_reach_succeeds_and_a_random_policy_does_not(dr: str) -> None:
    env = gym.make("Sim2Real/Arm3Reach-v0", dr=dr)
    wins = 0
    for seed in range(5):
        env.reset(seed=seed)
        out = _drive_to(env, env.unwrapped.task.target_m, 50)
        wins += out[4]["is_success"]
        assert out[3]  # truncated at 50 steps
    assert wins >= 4
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(50):
        *_, info = env.step(env.action_space.sample())
    assert not info["is_success"]
    env.close()


def test_scripted_grasp_lifts_the_cube_and_a_scripted_miss_does_not() -> None:
    env = gym.make("Sim2Real/Arm3Pick-v0", dr="default")
    u = env.unwrapped
    wins = 0
    for seed in range(4):
        env.reset(seed=seed)
        cube = u.task.cube_position(u).copy()
        _drive_to(env, cube + [0, 0, 0.06], 10, grip=1.0)
        _drive_to(env, cube, 10, grip=1.0)
        open_reward = _drive_to(env, cube, 1, grip=1.0)[1]
        assert not u.task.is_grasped(u)
        closed_reward = _drive_to(env, cube, 8, grip=-1.0)[1]
        assert u.task.is_grasped(u) and closed_reward > open_reward  # the grasp term pays
        out = _drive_to(env, cube + [0, 0, 0.09], 22, grip=-1.0)
        lifted = u.task.cube_position(u)[2] - cube[2]
        wins += out[4]["is_success"]
        assert out[4]["is_success"] == (lifted >= 0.05)
    assert wins >= 3
    # The miss: the same motion with the gripper left open leaves the cube on the table.
    env.reset(seed=0)
    cube = u.task.cube_position(u).copy()
    _drive_to(env, cube + [0, 0, 0.06], 10, grip=1.0)
    _drive_to(env, cube, 18, grip=1.0)
    out = _drive_to(env, cube + [0, 0, 0.09], 22, grip=1.0)
    assert not out[4]["is_success"] and not u.task.is_grasped(u)
    assert u.task.cube_position(u)[2] - cube[2] < 0.01
    env.close()


def test_scripted_seam_tracking_succeeds_and_standing_still_fails() -> None:
    env = gym.make("Sim2Real/Arm3Trace-v0", dr="none")
    u = env.unwrapped
    env.reset(seed=1)
    for _ in range(50):
        out = _drive_to(env, u.task.target_m + u.task.velocity_m_s * u.control_dt_s, 1)
    assert out[3] and out[4]["is_success"], u.task.mean_tracking_error_m
    env.reset(seed=1)
    for _ in range(50):
        out = env.step(np.zeros(3, dtype=np.float32))
    assert not out[4]["is_success"]
    env.close()
