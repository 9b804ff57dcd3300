"""``Task.placement``: a world that places objects from it rebuilds the env's own episode."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import sim2real.envs  # noqa: F401
from sim2real.deploy.worlds import SceneObjects
from sim2real.model import RigSpec


def _placed(env_id: str, seed: int) -> tuple[gym.Env, mujoco.MjData]:
    """The env after a seeded reset, and a fresh state of its model with the placement put in
    by the deploy worlds' ``SceneObjects``."""
    env = gym.make(env_id, dr="none")
    env.reset(seed=seed)
    u = env.unwrapped
    data = mujoco.MjData(u.model)
    SceneObjects(u.model, RigSpec()).place(data, u.task.placement(u))
    mujoco.mj_forward(u.model, data)
    return env, data


@pytest.mark.parametrize("seed", [0, 7, 1_000_003])
def test_pick_placement_puts_the_cube_where_the_env_did(seed: int) -> None:
    env, data = _placed("Sim2Real/Arm3Pick-v0", seed)
    u = env.unwrapped
    body = u.model.body("cube").id
    np.testing.assert_allclose(data.xpos[body], u.data.xpos[body], atol=1e-9)
    # the same yaw: the cube's rotation matrices agree (up to the quaternion's sign)
    np.testing.assert_allclose(data.xmat[body], u.data.xmat[body], atol=1e-9)
    env.close()


def test_pick_placements_differ_between_seeds() -> None:
    env = gym.make("Sim2Real/Arm3Pick-v0", dr="none")
    u = env.unwrapped
    cubes = []
    for seed in (1, 2):
        env.reset(seed=seed)
        cubes.append(u.task.placement(u)["cube"])
    assert not np.allclose(cubes[0], cubes[1])
    env.close()


def test_trace_placement_lays_the_seam_where_the_env_did() -> None:
    env, data = _placed("Sim2Real/Arm3Trace-v0", 3)
    u = env.unwrapped
    seam = u.model.body_mocapid[u.model.body("seam").id]
    np.testing.assert_allclose(data.mocap_pos[seam][:2], u.data.mocap_pos[seam][:2], atol=1e-12)
    q_deploy, q_env = data.mocap_quat[seam], u.data.mocap_quat[seam]
    assert abs(abs(float(q_deploy @ q_env)) - 1.0) < 1e-12
    env.close()


def test_reach_placement_is_the_target() -> None:
    env, data = _placed("Sim2Real/Arm3Reach-v0", 5)
    u = env.unwrapped
    np.testing.assert_allclose(data.mocap_pos[0], u.data.mocap_pos[0], atol=1e-12)
    env.close()
