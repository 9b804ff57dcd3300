"""Arm3Env's command-side observation: ``joint_target`` is what was sent, not what was read."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

import sim2real.envs as envs
from sim2real.envs.base import Task
from sim2real.randomization.config import DRConfig


def _base(env: gym.Env[Any, Any]) -> envs.Arm3Env:
    u = env.unwrapped
    assert isinstance(u, envs.Arm3Env)
    return u


def _fields(env: gym.Env[Any, Any], obs: np.ndarray) -> dict[str, np.ndarray]:
    return _base(env).builder.split(obs)


def test_joint_target_integrates_the_decoded_actions_and_leads_a_lagging_servo() -> None:
    dr = DRConfig.from_dict("lag2", {"actuation": {"latency_steps": [2, 2]}})
    env = envs.make("reach", dr=dr, max_delta_rad=0.05)
    obs, _ = env.reset(seed=3)
    f = _fields(env, obs)
    # At rest on reset (readings are quantised to the servo resolution).
    np.testing.assert_allclose(f["joint_target"], f["joint_pos"], atol=1e-3)
    start = f["joint_target"].copy()
    action = np.array([1.0, -0.5, 0.25], dtype=np.float32)
    for k in range(1, 3):
        obs, *_ = env.step(action)
        f = _fields(env, obs)
        np.testing.assert_allclose(f["joint_target"], start + k * 0.05 * action, atol=1e-6)
    # Two steps of latency: the servo has not started moving, the command has.
    np.testing.assert_allclose(f["joint_pos"], start, atol=0.01)  # only settling under gravity
    assert np.abs(f["joint_target"] - f["joint_pos"]).max() > 0.09
    env.close()


def test_reach_observes_where_its_command_will_put_the_tool_before_the_servo_gets_there() -> None:
    dr = DRConfig.from_dict("lag2", {"actuation": {"latency_steps": [2, 2]}})
    env = envs.make("reach", dr=dr, max_delta_rad=0.05)
    u = _base(env)
    obs, _ = env.reset(seed=5)
    f = _fields(env, obs)
    # At rest the commanded pose is the pose (within servo sag and quantisation).
    np.testing.assert_allclose(f["target_ee_pos"], u.ee_position(), atol=0.005)
    action = np.array([1.0, -1.0, 1.0], dtype=np.float32)
    for _ in range(2):
        obs, *_ = env.step(action)
    f = _fields(env, obs)
    expected = u.spec_arm.forward_kinematics(f["joint_target"])
    np.testing.assert_allclose(f["target_ee_pos"], expected, atol=1e-6)
    np.testing.assert_allclose(f["target_goal_delta"], f["goal_pos"] - expected, atol=1e-6)
    # Two steps of latency: the camera still sees the old pose, the command already moved >1.5 cm.
    assert np.linalg.norm(f["target_ee_pos"] - f["ee_pos"]) > 0.015
    for _ in range(15):  # hold the command: the servo catches up with it
        obs, *_ = env.step(np.zeros(3, dtype=np.float32))
    np.testing.assert_allclose(u.ee_position(), expected, atol=0.006)
    env.close()


def test_goal_conditioned_reach_carries_the_commanded_pose_but_no_goal_delta() -> None:
    # HER relabels desired_goal, so the "observation" part must not depend on the goal.
    env = envs.make("Sim2Real/Arm3ReachGoal-v0")
    u = _base(env)
    names = [f.name for f in u.builder.layout()]
    assert "target_ee_pos" in names and "target_goal_delta" not in names
    env.reset(seed=3)
    obs, *_ = env.step(np.array([1.0, -1.0, 1.0], dtype=np.float32))
    f = _fields(env, obs["observation"])
    fk = u.spec_arm.forward_kinematics(f["joint_target"])
    np.testing.assert_allclose(f["target_ee_pos"], fk, atol=1e-6)
    env.close()
    pick = envs.make("pick")  # opted in: both fields, its goal is the lift point
    names = [f.name for f in _base(pick).builder.layout()]
    assert {"target_ee_pos", "target_goal_delta"} <= set(names)
    pick.close()
    assert not Task.command_fields  # a new task opts in
