"""Task logic on scripted action sequences with real physics: what succeeds and what fails."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import sim2real.envs  # noqa: F401
from sim2real.envs.base import Arm3Env
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.randomization.config import DRConfig, load_preset


def _rigid_default() -> DRConfig:
    """DR ``default`` without its kinematics: these scripts steer by the spec's own IK, and a horn
    off by up to 0.03 rad is what a policy corrects from its observation, not a script."""
    ranges = load_preset("default").to_dict()
    ranges.pop("kinematics", None)
    return DRConfig.from_dict("default-rigid", ranges)


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
    env = gym.make("Sim2Real/Arm3Pick-v0", dr=_rigid_default())
    u = env.unwrapped
    wins = 0
    for seed in range(8):  # DR default: a low-friction cube sometimes slips from a scripted grasp
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
    assert wins >= 5
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


HOLD = np.array([0.0, 0.0, 0.0, -1.0], dtype=np.float32)  # joints still, gripper closed


def _held(env: gym.Env, seed: int, height_m: float | None = None) -> tuple:
    opts: dict = {"start": "held"}
    if height_m is not None:
        opts["held_height_m"] = height_m
    return env.reset(seed=seed, options=opts)


@pytest.mark.parametrize("dr", ["none", "default"])
def test_a_held_start_has_the_cube_in_the_gripper_and_holding_still_keeps_it(dr: str) -> None:
    env = gym.make("Sim2Real/Arm3Pick-v0", dr=_rigid_default() if dr == "default" else dr)
    u = env.unwrapped
    layout = {f.name: slice(f.start, f.stop) for f in u.builder.layout()}
    for seed in range(6):
        env.reset(seed=seed)
        assert not u.task.is_grasped(u)  # the default start: cube on the table, gripper open
        rest = u.task.cube_position(u).copy()
        obs, info = _held(env, seed)
        assert info["start"] == "held" and u.task.is_grasped(u)
        np.testing.assert_allclose(u.task.cube_position(u)[:2], rest[:2], atol=0.01)
        assert np.linalg.norm(u.task.cube_position(u) - u.ee_position()) < 0.006
        # The command side reads as if the policy had been holding: targets are the pose, the
        # gripper is commanded closed and the last action is "hold".
        np.testing.assert_allclose(u.joint_positions(), u._targets[:3], atol=0.03)
        np.testing.assert_allclose(obs[layout["joint_target"]], u._targets, atol=1e-6)
        assert u._targets[3] == u.spec_arm.gripper.closed_rad
        np.testing.assert_array_equal(obs[layout["prev_action"]], HOLD)
        z0 = u.task.cube_position(u)[2]
        for _ in range(10):
            env.step(HOLD)
            assert u.task.is_grasped(u)
        assert abs(u.task.cube_position(u)[2] - z0) < 0.005
    env.close()


def test_a_held_start_honours_the_height_and_refuses_other_tasks_and_bad_values() -> None:
    env = gym.make("Sim2Real/Arm3Pick-v0", dr=_rigid_default())
    u = env.unwrapped
    env.reset(seed=2)
    rest_z = u.task.cube_position(u)[2]
    _held(env, 2, 0.04)
    assert u.task.is_grasped(u)
    assert u.task.cube_position(u)[2] - rest_z == pytest.approx(0.04, abs=0.004)
    with pytest.raises(ConfigError, match=r"held_height_m 0.2 not in \[0, 0.07\]"):
        _held(env, 2, 0.2)
    with pytest.raises(UnknownNameError, match="unknown start for task 'pick' 'flying'"):
        env.reset(seed=0, options={"start": "flying"})
    env.close()
    reach = gym.make("Sim2Real/Arm3Reach-v0")
    with pytest.raises(UnknownNameError, match="'held'; valid: default$"):
        reach.reset(seed=0, options={"start": "held"})
    assert reach.reset(seed=0)[1]["start"] == "default"
    reach.close()


def test_a_scripted_lift_from_a_held_start_succeeds_and_letting_go_does_not() -> None:
    env = gym.make("Sim2Real/Arm3Pick-v0", dr=_rigid_default())
    u = env.unwrapped
    wins = 0
    for seed in range(8):  # DR default: a low-friction cube sometimes slips from a scripted grasp
        _held(env, seed, 0.0)
        cube = u.task.cube_position(u).copy()
        out = _drive_to(env, cube + [0, 0, 0.09], 22, grip=-1.0)
        wins += out[4]["is_success"] and u.task.is_grasped(u)
    assert wins >= 5
    _held(env, 0, 0.0)
    cube = u.task.cube_position(u).copy()
    out = _drive_to(env, cube + [0, 0, 0.09], 22, grip=1.0)  # the gripper opens: no lift
    assert not out[4]["is_success"] and u.task.cube_position(u)[2] - cube[2] < 0.01
    env.close()


def test_the_lift_term_pays_for_height_only_while_grasped() -> None:
    from sim2real.envs.pick import LIFT_WEIGHT_PER_M

    env = gym.make("Sim2Real/Arm3Pick-v0", dr="none")
    u = env.unwrapped
    rewards, shaping = [], []
    for height_m in (0.0, 0.04):
        _held(env, 1, height_m)
        r = float(env.step(HOLD)[1])
        assert u.task.is_grasped(u)
        rewards.append(r)
        shaping.append(u.task.shaping(u))
    # The goal term alone pays 5·0.04 = 0.2 for the height; the lift term adds 10·0.04 = 0.4.
    assert rewards[1] - rewards[0] > 0.5
    assert shaping[1] - shaping[0] == pytest.approx(LIFT_WEIGHT_PER_M * 0.04, abs=0.06)
    # A cube up in the air that the fingers do not hold earns the approach term only.
    env.reset(seed=1)
    u.data.qpos[u.task._cube_qadr + 2] += 0.04
    mujoco.mj_forward(u.model, u.data)
    assert not u.task.is_grasped(u) and u.task.lift_m(u) == pytest.approx(0.04)
    reach = -2.0 * np.linalg.norm(u.ee_position() - u.task.cube_position(u))
    assert u.task.shaping(u) == pytest.approx(reach)
    env.close()
