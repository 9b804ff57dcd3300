"""Learning on a bare PWM arm (every reading the echo of its command): ArmEnv on SimArm's MuJoCo
pays pick's grasp from the tool and cube estimates, since the gripper reads "shut" whether it
holds the cube or nothing. On the lockstep clock, so the grasp does not depend on the load."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hardware.spec import load_spec
from sim2real.deploy.policy_io import io_for
from sim2real.deploy.runner import DeployOptions
from sim2real.envs.base import REWARDS
from sim2real.envs.pick import GRASP_BONUS, LIFT_M, LIFT_WEIGHT_PER_M
from sim2real.finetune.arm_env import ArmEnv
from tests.sim2real.deploy.conftest import pick_policy

PWM = load_spec(Path(__file__).parents[3] / "hardware" / "specs" / "arm3_mg996r_pwm.yaml")


def test_a_pwm_arm_is_paid_the_grasp_from_its_estimates() -> None:
    io = io_for(PWM, "Sim2Real/Arm3Pick-v0")
    env = ArmEnv(io, PWM, DeployOptions(backend="sim", sim_clock="lockstep"))
    grip = PWM.gripper
    assert grip is not None
    try:
        assert env.shaped
        obs, _ = env.reset(seed=2)
        act = pick_policy(PWM, io.builder, io.decoder)
        paid: list[tuple[float, dict[str, np.ndarray]]] = []
        truncated = False
        while not truncated:
            obs, reward, _, truncated, info = env.step(act(obs).astype(np.float32))
            f = io.builder.split(obs)
            d = float(np.linalg.norm(f["goal_delta"]))
            paid.append((reward - REWARDS[env.reward_name](d, d < 0.02), f))
        shut = [f for _, f in paid if abs(f["joint_pos"][-1] - grip.closed_rad) < 1e-3]
        assert shut, "the gripper never read shut"
        lifted = [s for s, f in paid if f["cube_pos"][2] - (f["goal_pos"][2] - LIFT_M) > 0.03]
        assert lifted, "the scripted grasp never lifted the cube 3 cm"
        assert max(lifted) > GRASP_BONUS + LIFT_WEIGHT_PER_M * 0.03 - 0.05, max(lifted)
        assert info["is_success"], info
    finally:
        env.close()
