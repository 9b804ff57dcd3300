"""The robosuite IIWA twin of the Kuka grasping task, with real robosuite, MuJoCo and pixels.

One env is built for the module (robosuite takes seconds to build); every test starts from its own
``reset(seed=...)``. The twin must pose the same task as the fast one: same spaces, same camera
relative to the tray, the same height hack, a scripted grasp that pays 1 and a miss that pays 0.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from sim2real.envs import kuka_objects as ko
from sim2real.envs.kuka_grasp import CAMERA, KukaGraspFastEnv
from sim2real.envs.kuka_robosuite import TRAY_ORIGIN_M, KukaGraspEnv
from sim2real.errors import Sim2RealError


def _index(family: str) -> int:
    return next(i for i, o in enumerate(ko.object_set("all")) if o.family == family)


@pytest.fixture(scope="module")
def env() -> Iterator[KukaGraspEnv]:
    e = KukaGraspEnv(dr="none", objects="all")
    yield e
    e.close()


def test_same_spaces_and_camera_as_the_fast_twin(env: KukaGraspEnv) -> None:
    fast = KukaGraspFastEnv(dr="none")
    try:
        assert env.action_space == fast.action_space
        assert env.observation_space == fast.observation_space
        m, f = env.model, fast.model
        rel = m.cam_pos[m.camera(CAMERA).id] - TRAY_ORIGIN_M
        np.testing.assert_allclose(rel, f.cam_pos[f.camera(CAMERA).id], atol=1e-9)
        np.testing.assert_allclose(
            m.cam_quat[m.camera(CAMERA).id], f.cam_quat[f.camera(CAMERA).id], atol=1e-6
        )
    finally:
        fast.close()
    obs, info = env.reset(seed=0)
    assert obs.shape == (48, 48, 3) and obs.dtype == np.uint8 and obs.std() > 10
    assert set(info["dr"]) == {
        "dynamics", "actuation", "sensing", "visual", "object", "kinematics"
    }  # fmt: skip


def test_arm_starts_at_the_target_and_follows_the_height_hack(env: KukaGraspEnv) -> None:
    env.reset(seed=1, options={"objects": [_index("box")]})
    env.set_object_pose(0, (0.07, 0.07))
    np.testing.assert_allclose(env.gripper_pose()[:3], env.target_pose()[:3], atol=0.004)
    for _ in range(env.task.descent_steps - 1):
        _, reward, term, _, _ = env.step(0)
        assert not term and reward == 0.0
        assert abs(env.gripper_pose()[2] - env.target_pose()[2]) < 0.012
    _, _, term, _, _ = env.step(0)
    assert term and env.steps == env.task.descent_steps


@pytest.mark.parametrize("family", ["box", "cylinder"])
def test_scripted_grasp_lifts_the_object_and_pays_1(env: KukaGraspEnv, family: str) -> None:
    env.reset(seed=2, options={"objects": [_index(family)]})
    obj = env.live_objects()[0]
    hx, hy = obj.half_extent_xy_m
    x, y = env.target_pose()[:2]
    env.set_object_pose(0, (x, y), 0.0 if hy <= hx else math.pi / 2)
    term, reward, info = False, 0.0, dict[str, Any]()
    while not term:
        _, reward, term, _, info = env.step(0)
    assert reward == 1.0 and info["is_success"] is True
    assert env.object_positions()[0, 2] > env.task.lift_success_m


def test_scripted_miss_pays_0(env: KukaGraspEnv) -> None:
    env.reset(seed=3, options={"objects": [_index("box")]})
    env.set_object_pose(0, (0.07, 0.07))
    term, reward, info = False, 0.0, dict[str, Any]()
    while not term:
        _, reward, term, _, info = env.step(4)  # -y: away from the object
    assert reward == 0.0 and info["is_success"] is False and info["distance_m"] > 0.1
    assert env.object_positions()[0, 2] < 0.05


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"robot": "KR6"}, "unknown robosuite robot 'KR6'; valid: IIWA, "),
        ({"gripper": "Hand"}, "unknown robosuite gripper 'Hand'; valid: BDGripper, "),
        ({"actions": "joystick"}, "unknown action mode 'joystick'"),
    ],
)
def test_bad_kwargs_are_one_line_errors(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(Sim2RealError, match=message) as info:
        KukaGraspEnv(**kwargs)
    assert "\n" not in str(info.value)
