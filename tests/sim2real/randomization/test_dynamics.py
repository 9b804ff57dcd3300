"""Dynamics DR's servo droop on real MuJoCo physics: the pitch joints settle that far below their
targets and the base does not (``test_appliers`` holds the planned writes to the reference's)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import sim2real.envs  # noqa: F401
from sim2real.randomization import DRConfig
from sim2real.randomization.config import Range

DROOP_RAD = 0.02


def _settled_error_rad(droop_rad: float) -> np.ndarray:
    """Joint angle minus target after the arm has held its targets for 2 s."""
    dr = DRConfig("droop", {"dynamics": {"actuator_droop_rad": Range(droop_rad, droop_rad)}})
    env = gym.make("Sim2Real/Arm3Reach-v0", dr=dr)
    try:
        env.reset(seed=3)
        hold = np.zeros(env.action_space.shape, dtype=np.float32)  # zero delta: hold the targets
        for _ in range(40):
            env.step(hold)
        u = env.unwrapped
        n = len(u.joint_positions())
        return np.asarray(u.joint_positions() - u._targets[:n])
    finally:
        env.close()


def test_droop_sags_the_pitch_joints_by_its_value_and_leaves_the_base() -> None:
    sag = _settled_error_rad(DROOP_RAD) - _settled_error_rad(0.0)
    assert sag[0] == pytest.approx(0.0, abs=1e-4)  # base yaw: gravity does not turn it
    # shoulder and elbow: the servo drives to target - droop (MuJoCo's own sag cancels out)
    np.testing.assert_allclose(sag[1:], -DROOP_RAD, atol=0.002)
