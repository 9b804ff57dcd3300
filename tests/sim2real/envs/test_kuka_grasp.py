"""The Kuka grasping replica's fast twin and its object set, with real MuJoCo physics and pixels.

Scripted episodes check the task logic end to end: the height hack lowers the gripper every step,
the grasp closes and lifts at the bottom, and the reward is 1 only when an object ends up above
the lift height.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import sim2real.envs  # noqa: F401  (registers the ids)
from sim2real.envs import kuka_objects as ko
from sim2real.envs.kuka_grasp import (
    DISCRETE_ACTIONS,
    IGNORED_DR_KEYS,
    MAX_SLOTS,
    PRIVILEGED_FIELDS,
    PRIVILEGED_INFO_KEY,
    PRIVILEGED_SCALE_M,
    GraspTask,
    KukaGraspFastEnv,
    privileged_teacher_action,
)
from sim2real.errors import ConfigError, Sim2RealError
from sim2real.randomization.base import TOUCHED_FIELDS
from sim2real.randomization.config import DRConfig, Range

FAST = "Sim2Real/KukaGraspFast-v0"
FAST_CONT = "Sim2Real/KukaGraspFastCont-v0"


def _one_per_family() -> dict[str, int]:
    """Catalogue index (split 'all') of the first object of each family."""
    out: dict[str, int] = {}
    for i, obj in enumerate(ko.object_set("all")):
        out.setdefault(obj.family, i)
    return out


def _across_fingers_yaw(obj: ko.ObjectSpec) -> float:
    """Object yaw that puts its narrow side across the fingers (which close along y)."""
    hx, hy = obj.half_extent_xy_m
    return 0.0 if hy <= hx else math.pi / 2


def _descend(env: gym.Env[Any, Any], action: Any = 0) -> tuple[float, dict[str, Any], int]:
    """Step ``action`` until the episode ends; (final reward, final info, steps taken)."""
    for n in range(1, 100):
        _, reward, term, trunc, info = env.step(action)
        assert not trunc
        if term:
            return float(reward), info, n
    raise AssertionError("episode did not end")


@pytest.fixture(scope="module")
def env() -> Iterator[KukaGraspFastEnv]:
    e = KukaGraspFastEnv(dr="none", objects="all")
    yield e
    e.close()


# ---- the object set ---------------------------------------------------------------------------
def test_object_set_is_generated_identically_with_every_family_in_both_splits() -> None:
    a = ko.generate_object_set(ko.OBJECT_SET_SEED, ko.OBJECT_SET_SIZE)
    assert a == ko.generate_object_set(ko.OBJECT_SET_SEED, ko.OBJECT_SET_SIZE)
    assert a != ko.generate_object_set(ko.OBJECT_SET_SEED + 1, ko.OBJECT_SET_SIZE)
    train, test = ko.object_set("train"), ko.object_set("test")
    assert len(train) + len(test) == len(a) == 100
    assert not {o.name for o in train} & {o.name for o in test}
    for split in (train, test):
        assert {o.family for o in split} == set(ko.FAMILIES)
    for obj in a:
        ext = np.array(obj.extents_m)
        assert np.all(ext >= ko.MIN_EXTENT_M - 1e-9) and np.all(ext <= ko.MAX_EXTENT_M + 1e-9)


def test_catalogue_mass_properties_come_from_mujoco_and_match_the_solids() -> None:
    cat = ko.catalog("all")
    for i, obj in enumerate(cat.objects):
        if obj.family == "box":
            hx, hy, hz = obj.parts[0].size_m
            assert cat.mass_kg[i] == pytest.approx(obj.density_kg_m3 * 8 * hx * hy * hz, rel=1e-4)
        if obj.family == "cylinder":
            r, h = obj.parts[0].size_m[:2]
            assert cat.mass_kg[i] == pytest.approx(
                obj.density_kg_m3 * math.pi * r * r * 2 * h, rel=1e-4
            )
    # An L shape's centre of mass sits off its bounding-box centre, towards the corner.
    ell = next(i for i, o in enumerate(cat.objects) if o.family == "l_shape")
    assert np.all(cat.ipos_m[ell, :2] < 0)


def test_unknown_split_and_bad_object_requests_are_one_line_errors() -> None:
    with pytest.raises(Sim2RealError, match="unknown object split 'val'; valid: all, test, train"):
        ko.object_set("val")
    e = KukaGraspFastEnv(dr="none")
    try:
        for bad in ([], [0, 0], [999], [0.5], list(range(6))):
            with pytest.raises(ConfigError, match=r"options\['objects'\]") as info:
                e.reset(seed=0, options={"objects": bad})
            assert "\n" not in str(info.value)
    finally:
        e.close()


# ---- height hack, grasp and lift --------------------------------------------------------------
def test_height_hack_lowers_the_gripper_every_step_and_ends_at_the_bottom(
    env: KukaGraspFastEnv,
) -> None:
    t = env.task
    env.reset(seed=1, options={"objects": [0]})
    env.set_object_pose(0, (0.07, 0.07))  # nothing under the gripper to land on
    z_prev = env.target_pose()[2]
    for _ in range(1, t.descent_steps):
        _, reward, term, _, info = env.step(0)
        z = env.target_pose()[2]
        assert z == pytest.approx(z_prev - t.descent_m_per_step)
        assert abs(env.gripper_pose()[2] - z) < 0.006  # the gripper follows the target
        assert not term and reward == 0.0 and info["is_success"] is False
        z_prev = z
    _, _, term, _, _ = env.step(0)
    assert term and env.steps == t.descent_steps
    # Past the end nothing moves and the outcome repeats with no further reward.
    pose = env.gripper_pose()
    _, reward, term, _, _ = env.step(1)
    assert term and reward == 0.0 and np.array_equal(env.gripper_pose(), pose)


@pytest.mark.parametrize("family", sorted(ko.FAMILIES))
def test_scripted_grasp_of_each_family_lifts_the_object_and_pays_1(
    env: KukaGraspFastEnv, family: str
) -> None:
    index = _one_per_family()[family]
    env.reset(seed=2, options={"objects": [index]})
    x, y = env.target_pose()[:2]
    env.set_object_pose(0, (x, y), _across_fingers_yaw(env.live_objects()[0]))
    reward, info, n = _descend(env, 0)
    assert n == env.task.descent_steps
    assert reward == 1.0 and info["is_success"] is True
    assert env.object_positions()[0, 2] > env.task.lift_success_m
    assert info["distance_m"] < 0.01  # measured when the gripper closed


def test_scripted_miss_next_to_the_objects_pays_0(env: KukaGraspFastEnv) -> None:
    family = _one_per_family()
    env.reset(seed=3, options={"objects": [family["box"], family["cylinder"]]})
    env.set_object_pose(0, (0.06, 0.06))
    env.set_object_pose(1, (0.06, -0.02))
    for _ in range(5):  # -x: away from both objects
        env.step(2)
    reward, info, _ = _descend(env, 0)
    assert reward == 0.0 and info["is_success"] is False
    assert info["distance_m"] > 0.1
    assert np.all(env.object_positions()[:, 2] < 0.05)  # both still on the tray floor


def test_closing_at_the_last_step_above_the_bottom_misses(env: KukaGraspFastEnv) -> None:
    """``max_episode_steps`` below the descent: the gripper closes in mid-air."""
    e = KukaGraspFastEnv(dr="none", objects="all", max_episode_steps=4)
    try:
        e.reset(seed=4, options={"objects": [_one_per_family()["box"]]})
        x, y = e.target_pose()[:2]
        e.set_object_pose(0, (x, y), _across_fingers_yaw(e.live_objects()[0]))
        reward, _, n = _descend(e, 0)
        assert n == 4 and reward == 0.0 and e.target_pose()[2] == pytest.approx(e.task.lift_to_m)
    finally:
        e.close()


# ---- actions and pixels -------------------------------------------------------------------------
def test_discrete_actions_move_the_target_by_one_step_and_the_gripper_follows(
    env: KukaGraspFastEnv,
) -> None:
    t = env.task
    expected = DISCRETE_ACTIONS * [t.xy_step_m, t.xy_step_m, t.yaw_step_rad]
    for a, delta in enumerate(expected):
        env.reset(seed=5)
        before = env.target_pose()
        env.step(a)
        env.step(np.array(a))  # a 0-d array, as a vectorised policy sends it
        moved = env.target_pose() - before
        np.testing.assert_allclose(moved[[0, 1, 3]], 2 * delta, atol=1e-12)
        assert moved[2] == pytest.approx(-2 * t.descent_m_per_step)
    env.reset(seed=5)
    x0 = env.gripper_pose()[0]
    for _ in range(4):
        env.step(1)
    assert env.gripper_pose()[0] - x0 == pytest.approx(4 * t.xy_step_m, abs=0.004)


def test_continuous_variant_scales_and_clips_like_the_discrete_table() -> None:
    e = gym.make(FAST_CONT, dr="none")
    d = gym.make(FAST, dr="none")
    try:
        assert e.action_space == gym.spaces.Box(-1.0, 1.0, (3,), np.float32)
        assert d.action_space == gym.spaces.Discrete(7)
        assert e.observation_space == d.observation_space
        e.reset(seed=6)
        d.reset(seed=6)
        e.step(np.array([2.0, 0.0, -0.5]))  # clipped to +1 in x
        d.step(1)
        ue, ud = e.unwrapped, d.unwrapped
        assert isinstance(ue, KukaGraspFastEnv) and isinstance(ud, KukaGraspFastEnv)
        assert ue.target_pose()[0] == pytest.approx(ud.target_pose()[0])
        assert ue.target_pose()[3] == pytest.approx(-0.5 * ue.task.yaw_step_rad)
    finally:
        e.close()
        d.close()


@pytest.mark.parametrize(
    ("action", "message"),
    [
        (7, r"discrete action 7 not in \[0, 6\]"),
        (2.5, r"discrete action 2.5 not in \[0, 6\]"),
        (np.array([1, 2]), "must be one integer"),
        (np.nan, "must be one integer"),
    ],
)
def test_bad_discrete_actions_are_named(env: KukaGraspFastEnv, action: Any, message: str) -> None:
    env.reset(seed=0)
    with pytest.raises(ConfigError, match=message):
        env.step(action)


def test_bad_continuous_actions_and_kwargs_are_one_line_errors() -> None:
    e = gym.make(FAST_CONT, dr="none")
    try:
        e.reset(seed=0)
        with pytest.raises(ConfigError, match="contains NaN"):
            e.step(np.array([np.nan, 0.0, 0.0]))
        with pytest.raises(ConfigError, match="must have 3 values"):
            e.step(np.zeros(2))
    finally:
        e.close()
    cases: list[tuple[dict[str, Any], str]] = [
        ({"actions": "joystick"}, "unknown action mode 'joystick'; valid: continuous, discrete"),
        ({"image_size": 50}, r"image_size 50 not one of \[48, 64, 84, 96, 128\]"),
        ({"objects": "val"}, "unknown object split 'val'"),
        ({"dr": "wild"}, "unknown DR preset 'wild'"),
        ({"max_episode_steps": 0}, "max_episode_steps 0 must be an integer >= 1"),
    ]
    for kwargs, message in cases:
        with pytest.raises(Sim2RealError, match=message) as info:
            KukaGraspFastEnv(**kwargs)
        assert "\n" not in str(info.value)
    with pytest.raises(ConfigError, match="bottom 0.2 < start 0.158"):
        GraspTask(bottom_height_m=0.2)


def test_pixels_show_the_tray_and_change_when_the_gripper_moves() -> None:
    for size in (48, 84):
        e = KukaGraspFastEnv(dr="none", image_size=size)
        try:
            obs, _ = e.reset(seed=7)
            assert obs.shape == (size, size, 3) and obs.dtype == np.uint8
            assert obs.std() > 10
            after = obs
            for _ in range(3):
                after, *_ = e.step(1)
            assert np.abs(after.astype(int) - obs.astype(int)).sum() > 0
        finally:
            e.close()


# ---- domain randomisation ----------------------------------------------------------------------
def _preset(name: str, **ranges: dict[str, tuple[float, float]]) -> DRConfig:
    return DRConfig(
        name, {cat: {k: Range(*v) for k, v in keys.items()} for cat, keys in ranges.items()}
    )


def test_object_dr_scales_the_slots_and_restore_nominal_is_bit_exact() -> None:
    dr = _preset(
        "big",
        object={"size_scale": (1.2, 1.2), "mass_scale": (2.0, 2.0), "friction": (0.7, 0.7)},
        visual={"camera_pos_jitter_m": (0.01, 0.01), "light_diffuse_scale": (0.5, 0.5)},
        dynamics={"actuator_gain_scale": (0.8, 0.8)},
    )
    e = KukaGraspFastEnv(dr=dr, objects="all")
    fresh = KukaGraspFastEnv(dr="none", objects="all")
    try:
        _, info = e.reset(seed=8, options={"objects": [0, 1]})
        assert set(info["dr"]) == {
            "dynamics",
            "actuation",
            "sensing",
            "visual",
            "object",
            "kinematics",
        }
        m, cat = e.model, e.catalog
        g = e.slots[0].geoms[0]
        np.testing.assert_allclose(m.geom_size[g], cat.geom_size[0, 0] * 1.2)
        assert m.body_mass[e.slots[1].body] == pytest.approx(cat.mass_kg[1] * 2.0)
        assert m.geom_friction[g, 0] == pytest.approx(0.7)
        cam = m.camera("tray_cam").id
        assert np.linalg.norm(m.cam_pos[cam] - fresh.model.cam_pos[cam]) == pytest.approx(0.01)
        e.restore_nominal()
        for field in TOUCHED_FIELDS:
            np.testing.assert_array_equal(getattr(m, field), getattr(fresh.model, field), field)
    finally:
        e.close()
        fresh.close()


def test_latency_dr_delays_the_first_move_by_one_step() -> None:
    e = KukaGraspFastEnv(dr=_preset("late", actuation={"latency_steps": (1, 1)}))
    try:
        e.reset(seed=9)
        x0 = e.target_pose()[0]
        e.step(1)
        assert e.target_pose()[0] == pytest.approx(x0)  # the first +x arrives one step late
        e.step(0)
        assert e.target_pose()[0] == pytest.approx(x0 + e.task.xy_step_m)
    finally:
        e.close()


def _rollout(dr: str | DRConfig) -> list[np.ndarray]:
    e = KukaGraspFastEnv(dr=dr)
    try:
        obs, _ = e.reset(seed=11)
        trace = [obs]
        for a in (1, 3, 5, 0, 2, 4, 6, 1, 1, 3, 0, 0):
            obs, reward, *_ = e.step(a)
            trace += [obs, np.array(reward)]
        return trace
    finally:
        e.close()


def test_keys_listed_as_ignored_change_nothing_and_an_applied_one_does() -> None:
    """Point ranges draw no random numbers, so only the key's own effect could differ."""
    points = {"deadband_rad": 0.01, "quantisation_rad": 0.003, "joint_noise_rad": 0.01}
    points |= {"joint_bias_rad": 0.02, "stereo_pixel_noise_px": 0.5}
    points |= {"position_bias_m": 0.01, "obs_delay_steps": 1.0}
    points |= {"link_length_delta_m": 0.004, "joint_offset_rad": 0.03, "tool_offset_delta_m": 0.003}
    reference = _rollout("none")
    for category, keys in IGNORED_DR_KEYS.items():
        for key in keys:
            v = points[key]
            same = _rollout(_preset(key, **{category: {key: (v, v)}}))
            for a, b in zip(reference, same, strict=True):
                np.testing.assert_array_equal(a, b, err_msg=f"{category}.{key}")
    slower = _rollout(_preset("slow", actuation={"max_speed_scale": (0.5, 0.5)}))
    assert any(not np.array_equal(a, b) for a, b in zip(reference, slower, strict=True))


def test_settled_scene_has_no_deep_penetration(env: KukaGraspFastEnv) -> None:
    """Objects placed by the reset rest on the tray instead of sinking into it or each other."""
    for seed in range(5):
        env.reset(seed=seed)
        d = env.data
        depths = [d.contact[i].dist for i in range(d.ncon)]
        assert min(depths, default=0.0) > -0.003
        assert np.all(env.object_positions()[:, 2] > 0.0)
        mujoco.mj_step(env.model, d, nstep=20)
        assert np.all(np.abs(d.qvel) < 0.1)  # at rest: nothing rolls or slides away


# ---- a 500-step DQN smoke run -----------------------------------------------------------------------
def test_dqn_cnn_policy_trains_500_steps_on_the_discrete_env() -> None:
    import torch
    from stable_baselines3 import DQN

    torch.set_num_threads(1)
    e = gym.make(FAST, dr="default")
    model = DQN(
        "CnnPolicy",
        e,
        buffer_size=500,
        learning_starts=100,
        train_freq=4,
        batch_size=32,
        target_update_interval=100,
        seed=0,
        device="cpu",
    )
    before = [p.detach().clone() for p in model.q_net.parameters()]
    model.learn(total_timesteps=500)
    buffer = model.replay_buffer
    assert buffer is not None and model.num_timesteps == 500 and buffer.size() == 500
    assert buffer.observations.shape[-3:] == (3, 48, 48)  # channel-first CNN input
    assert any(not torch.equal(a, b) for a, b in zip(before, model.q_net.parameters(), strict=True))
    obs, _ = e.reset(seed=10)
    action, _ = model.predict(obs, deterministic=True)
    assert e.action_space.contains(int(action))
    e.close()


# ---- the privileged state (critics and teachers only) -------------------------------------------
def test_privileged_state_is_in_info_at_reset_and_step_and_never_in_the_observation(
    env: KukaGraspFastEnv,
) -> None:
    family = _one_per_family()
    obs, info = env.reset(seed=4, options={"objects": [family["box"], family["cylinder"]]})
    assert isinstance(obs, np.ndarray) and obs.shape == (48, 48, 3)  # pixels only
    assert env.privileged_space.shape == (len(PRIVILEGED_FIELDS),)
    for _ in range(3):
        priv = info[PRIVILEGED_INFO_KEY]
        assert priv.dtype == np.float32 and env.privileged_space.contains(priv)
        tgt, objs = env.target_pose(), env.object_positions()
        slots = priv[5:].reshape(MAX_SLOTS, 4)
        np.testing.assert_allclose(priv[:3], tgt[:3] / PRIVILEGED_SCALE_M, rtol=1e-6)
        assert priv[4] == pytest.approx(env.steps / env.max_episode_steps)
        np.testing.assert_array_equal(slots[:, 0], [1, 1, 0, 0, 0])  # two live objects
        expected = (objs[:, :2] - tgt[:2]) / PRIVILEGED_SCALE_M
        np.testing.assert_allclose(slots[:2, 1:3], expected, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(slots[:2, 3], objs[:, 2] / PRIVILEGED_SCALE_M, rtol=1e-5)
        assert not slots[2:].any()
        _, _, _, _, info = env.step(1)


@pytest.mark.parametrize(
    ("offset_m", "action"),
    [
        ((0.05, 0.01), 1),
        ((-0.05, 0.02), 2),
        ((0.01, 0.04), 3),
        ((-0.01, -0.05), 4),
        ((0.0, 0.0), 0),
    ],
)
def test_teacher_steers_along_the_larger_error_to_the_object(
    env: KukaGraspFastEnv, offset_m: tuple[float, float], action: int
) -> None:
    env.reset(seed=5, options={"objects": [_one_per_family()["box"]]})
    x, y = env.target_pose()[:2]
    env.set_object_pose(0, (x + offset_m[0], y + offset_m[1]))
    assert privileged_teacher_action(env.privileged_state()) == action


def test_teacher_grasps_an_offset_object_with_real_physics(env: KukaGraspFastEnv) -> None:
    env.reset(seed=6, options={"objects": [_one_per_family()["box"]]})
    x, y = env.target_pose()[:2]
    env.set_object_pose(0, (x + 0.045, y - 0.03), _across_fingers_yaw(env.live_objects()[0]))
    priv = env.privileged_state()
    actions = []
    term, reward = False, 0.0
    while not term:
        actions.append(privileged_teacher_action(priv))
        _, reward, term, _, info = env.step(actions[-1])
        priv = info[PRIVILEGED_INFO_KEY]
    assert actions.count(1) == 3 and actions.count(4) == 2  # 4.5 cm of +x, 3 cm of -y
    assert reward == 1.0


def test_teacher_rejects_a_state_of_the_wrong_size() -> None:
    with pytest.raises(ConfigError, match="privileged state has 3 values"):
        privileged_teacher_action(np.zeros(3))
