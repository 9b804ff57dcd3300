"""The robosuite backend with real robosuite and MuJoCo physics: tasks, DR, sensing, pixels, errors.

robosuite envs take about a second to build, so each module-scoped fixture builds one and the
tests reuse it (every test starts from its own ``reset(seed=...)``).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import sim2real.envs  # noqa: F401  (registers the ids)
from sim2real.errors import Sim2RealError
from sim2real.randomization.config import DRConfig, Range

LIFT = "Sim2Real/RobosuiteLift-v0"
REACH = "Sim2Real/RobosuiteReach-v0"


def _preset(name: str, **ranges: dict[str, tuple[float, float]]) -> DRConfig:
    """Everything neutral except the given category → key → (low, high)."""
    return DRConfig(
        name, {cat: {k: Range(*v) for k, v in keys.items()} for cat, keys in ranges.items()}
    )


def _model_arrays(model: Any) -> dict[str, np.ndarray]:
    out = {}
    for key in dir(model):
        if key.startswith("_"):
            continue
        try:
            value = getattr(model, key)
        except Exception:  # some MjModel attributes raise when read
            continue
        if isinstance(value, np.ndarray):
            out[key] = value.copy()
    return out


def _split(env: gym.Env, obs: np.ndarray) -> dict[str, np.ndarray]:
    return env.unwrapped.builder.split(obs)


@pytest.fixture(scope="module")
def reach() -> Iterator[gym.Env]:
    env = gym.make(REACH, dr="none")
    yield env
    env.close()


@pytest.fixture(scope="module")
def lift_default() -> Iterator[gym.Env]:
    env = gym.make(LIFT, dr="default")
    yield env
    env.close()


# ---- bad input ----------------------------------------------------------------------------
ROBOTS = "IIWA, Jaco, Kinova3, Panda, PandaDexLH, PandaDexRH, Sawyer, UR5e, XArm7"
CONTROLLERS = "JOINT_POSITION, JOINT_TORQUE, OSC_POSE, OSC_POSITION"


@pytest.mark.parametrize(
    ("env_id", "kwargs", "message"),
    [
        (LIFT, {"robot": "Pandaa"}, f"unknown robosuite robot 'Pandaa'; valid: {ROBOTS}"),
        (LIFT, {"robot": "Baxter"}, f"unknown robosuite robot 'Baxter'; valid: {ROBOTS}"),
        (
            LIFT,
            {"controller": "JOINT_VELOCITY"},
            f"unknown robosuite controller 'JOINT_VELOCITY'; valid: {CONTROLLERS}",
        ),
        (REACH, {"controller": "IK_POSE"}, "unknown robosuite controller 'IK_POSE'; valid: "),
        (LIFT, {"reward": "distance"}, "unknown lift reward 'distance'; valid: shaped, sparse"),
        (REACH, {"reward": "shaped"}, "unknown reach reward 'shaped'; valid: distance, sparse"),
        (LIFT, {"obs_mode": "goal"}, "unknown obs_mode 'goal'; valid: pixels, state"),
        (LIFT, {"dr": "wild"}, "unknown DR preset 'wild'; valid: default, none, shifted, strong"),
        (REACH, {"control_hz": 1000}, r"control_hz 1000 not in \[1, 250\]"),
        (REACH, {"image_size": 50}, "image_size 50 not one of"),
        (
            REACH,
            {"camera": "cam_left"},
            "unknown camera 'cam_left'; valid: agentview, birdview, frontview, robot0_eye_in_hand",
        ),
    ],
)
def test_bad_input_gets_a_one_line_error_listing_the_valid_choices(
    env_id: str, kwargs: dict[str, Any], message: str
) -> None:
    with pytest.raises(Sim2RealError, match=message) as info:
        gym.make(env_id, **kwargs)
    assert "\n" not in str(info.value)


# ---- the wrapped robosuite env ---------------------------------------------------------------
def test_wrapped_robosuite_env_is_reachable_and_set_up_for_speed(reach: gym.Env) -> None:
    rs = reach.unwrapped.robosuite_env
    assert type(rs).__name__ == "Sim2RealReach"
    assert rs.hard_reset is False
    assert rs.enabled_observables == set()  # we read MjData directly
    assert rs.control_freq == 20 and reach.unwrapped.frame_skip == 25  # 500 Hz physics
    lift = gym.make(LIFT, dr="none", robot="IIWA")
    try:
        rs = lift.unwrapped.robosuite_env
        assert type(rs).__name__ == "Lift" and type(rs.robots[0]).__name__ == "FixedBaseRobot"
        assert rs.robots[0].name == "IIWA"
        assert lift.action_space.shape == (7,)  # OSC_POSE (6) + gripper (1)
    finally:
        lift.close()


def test_reach_targets_are_seeded_and_lie_in_the_workspace_box(reach: gym.Env) -> None:
    rs = reach.unwrapped.robosuite_env
    targets = []
    for seed in range(6):
        reach.reset(seed=seed)
        targets.append(rs.target_position().copy())
    targets_a = np.array(targets)
    rel = targets_a - rs.table_offset
    assert np.all(rel >= rs.target_low_m) and np.all(rel <= rs.target_high_m)
    assert len({tuple(t) for t in targets_a}) == 6
    reach.reset(seed=3)
    np.testing.assert_array_equal(rs.target_position(), targets_a[3])


# ---- tasks with scripted policies ------------------------------------------------------------
def _scripted_reach(env: gym.Env, seed: int) -> dict[str, Any]:
    """Move toward the observed target with the OSC_POSITION delta command (5 cm per unit)."""
    obs, _ = env.reset(seed=seed)
    info: dict[str, Any] = {}
    for _ in range(50):
        action = np.clip(_split(env, obs)["goal_delta"] / 0.05, -1.0, 1.0)
        obs, _, term, trunc, info = env.step(action)
        assert not term
    assert trunc  # 50 steps at 20 Hz, as the native reach
    return info


def test_scripted_reach_gets_within_1cm_and_a_random_policy_does_not(reach: gym.Env) -> None:
    for seed in range(2):
        info = _scripted_reach(reach, seed)
        assert info["is_success"] and info["distance_m"] < 0.01
    reach.action_space.seed(0)
    for seed in range(2):
        reach.reset(seed=seed)
        for _ in range(50):
            _, reward, _, _, info = reach.step(reach.action_space.sample())
        assert not info["is_success"] and info["distance_m"] > 0.01
        assert reward == pytest.approx(-5.0 * info["distance_m"])  # the native "distance" reward


def test_scripted_reach_works_for_another_robot_and_controller() -> None:
    env = gym.make(REACH, dr="none", robot="IIWA", controller="OSC_POSE")
    try:
        assert env.action_space.shape == (6,)
        obs, _ = env.reset(seed=1)
        for _ in range(50):
            action = np.zeros(6)
            action[:3] = np.clip(_split(env, obs)["goal_delta"] / 0.05, -1.0, 1.0)
            obs, _, _, _, info = env.step(action)
        assert info["is_success"], info
    finally:
        env.close()


def _scripted_lift(env: gym.Env, seed: int, close: bool = True) -> tuple[dict[str, Any], float]:
    """Above the cube, down, close (or not), up: from the observation only."""
    obs, _ = env.reset(seed=seed)
    o = _split(env, obs)
    start, phase, closed_at = o["cube_pos"].copy(), 0, 0
    info: dict[str, Any] = {}
    reward = 0.0
    for t in range(env.unwrapped.max_episode_steps):
        ee, cube = o["ee_pos"], o["cube_pos"]
        goal = {0: cube + [0.0, 0.0, 0.06], 1: cube, 2: cube}.get(phase, start + [0.0, 0.0, 0.12])
        if phase < 2 and np.linalg.norm(goal - ee) < 0.01:
            phase, closed_at = phase + 1, t
        if phase == 2 and t - closed_at > 8:
            phase = 3
        action = np.zeros(7)
        action[:3] = np.clip((goal - ee) / 0.05, -1.0, 1.0)
        action[6] = 1.0 if (close and phase >= 2) else -1.0
        obs, reward, _, _, info = env.step(action)
        o = _split(env, obs)
    return info, float(reward)


def test_scripted_lift_succeeds_under_default_dr_and_fails_without_closing(
    lift_default: gym.Env,
) -> None:
    for seed in (0, 1):
        info, reward = _scripted_lift(lift_default, seed)
        assert info["is_success"] and info["distance_m"] == 0.0
        assert reward == pytest.approx(1.0)  # robosuite's normalised success reward
    info, reward = _scripted_lift(lift_default, 0, close=False)
    assert (
        not info["is_success"] and info["distance_m"] > 0.01 and reward < 1.0
    )  # still on the table


# ---- domain randomisation --------------------------------------------------------------------
def test_dr_writes_every_category_and_restores_the_model_bit_for_bit() -> None:
    env = gym.make(LIFT, dr="strong", render_mode="rgb_array")  # renders: visual DR applies
    u = env.unwrapped
    try:
        env.reset(seed=0)
        u.restore_nominal()
        nominal = _model_arrays(u.model)
        for seed in (1, 2):
            env.reset(seed=seed)
            for _ in range(3):
                env.step(env.action_space.sample())
        changed = {
            k for k, v in _model_arrays(u.model).items() if not np.array_equal(v, nominal[k])
        }
        expected = {
            "body_mass",  # dynamics (DynamicsModder) and object
            "body_inertia",
            "dof_damping",
            "dof_frictionloss",
            "dof_armature",
            "actuator_gainprm",
            "light_diffuse",  # visual (LightingModder, CameraModder, colours)
            "light_pos",
            "cam_pos",
            "cam_fovy",
            "geom_rgba",
            "geom_size",  # object
            "geom_friction",
        }
        assert expected <= changed
        u.restore_nominal()
        after = _model_arrays(u.model)
        assert [k for k in after if not np.array_equal(after[k], nominal[k])] == []
    finally:
        env.close()


def test_dynamics_and_object_values_follow_the_sampled_parameters(lift_default: gym.Env) -> None:
    u = lift_default.unwrapped
    _, info = lift_default.reset(seed=7)
    p, nom, ids, m = info["dr"], u.randomizer.nominal, u.targets.ids, u.model
    b, d, a = ids.arm_bodies, ids.arm_dofs, ids.servo_actuators
    dyn, obj = p["dynamics"], p["object"]
    np.testing.assert_allclose(m.body_mass[b], nom["body_mass"][b] * dyn["link_mass_scale"])
    np.testing.assert_allclose(m.dof_damping[d], nom["dof_damping"][d] * dyn["joint_damping_scale"])
    np.testing.assert_allclose(
        m.dof_frictionloss[d], nom["dof_frictionloss"][d] + dyn["joint_frictionloss_nm"]
    )
    np.testing.assert_allclose(
        m.actuator_gainprm[a, 0], nom["actuator_gainprm"][a, 0] * dyn["actuator_gain_scale"]
    )
    cube, vis = ids.cube_geom, u.targets.object_visual_geoms
    np.testing.assert_allclose(m.geom_size[cube], nom["geom_size"][cube] * obj["size_scale"])
    np.testing.assert_allclose(m.geom_size[vis], nom["geom_size"][vis] * obj["size_scale"])
    assert m.geom_friction[cube, 0] == pytest.approx(obj["friction"])
    # Visual DR is sampled but not written when nothing renders (saves time, changes nothing).
    np.testing.assert_array_equal(m.light_diffuse, nom["light_diffuse"])
    np.testing.assert_array_equal(m.geom_rgba, nom["geom_rgba"])


def test_actuation_latency_delays_the_command_and_speed_scale_shortens_the_step() -> None:
    """Point ranges draw no random numbers, so all three envs start from the same state."""
    envs = {
        "none": gym.make(REACH, dr="none"),
        "latency": gym.make(REACH, dr=_preset("lat", actuation={"latency_steps": (2, 2)})),
        "slow": gym.make(REACH, dr=_preset("slow", actuation={"max_speed_scale": (0.5, 0.5)})),
    }
    try:
        ee = {}
        for name, env in envs.items():
            env.reset(seed=4)
            start = env.unwrapped.ee_position().copy()
            trace = []
            for _ in range(6):
                env.step(np.array([1.0, 0.0, 0.0]))
                trace.append(env.unwrapped.ee_position() - start)
            ee[name] = np.array(trace)
        idle = gym.make(REACH, dr="none")
        idle.reset(seed=4)
        start = idle.unwrapped.ee_position().copy()
        idle_trace = []
        for _ in range(2):
            idle.step(np.zeros(3))
            idle_trace.append(idle.unwrapped.ee_position() - start)
        idle.close()
        # Two steps of latency: the arm holds (idle command), then starts to move.
        np.testing.assert_array_equal(ee["latency"][:2], np.array(idle_trace))
        assert ee["latency"][2, 0] > 0.005
        # Half speed: about half the distance along x after the same commands.
        ratio = ee["slow"][-1, 0] / ee["none"][-1, 0]
        assert 0.35 < ratio < 0.65, ratio
    finally:
        for env in envs.values():
            env.close()


def test_sensing_bias_and_stereo_noise_reach_the_observation(reach: gym.Env) -> None:
    obs, _ = reach.reset(seed=2)  # dr none: exact readings
    o, u = _split(reach, obs), reach.unwrapped
    np.testing.assert_allclose(o["joint_pos"], u.joint_positions(), atol=1e-6)
    np.testing.assert_allclose(o["ee_pos"], u.ee_position(), atol=1e-6)
    target = u.to_base(u.robosuite_env.target_position())[0]
    np.testing.assert_allclose(o["goal_pos"], target, atol=1e-6)
    noisy = gym.make(
        REACH,
        dr=_preset(
            "sense",
            sensing={"joint_bias_rad": (0.03, 0.03), "stereo_pixel_noise_px": (0.5, 0.5)},
        ),
    )
    try:
        errors = []
        obs, _ = noisy.reset(seed=2)
        for _ in range(20):
            o, n = _split(noisy, obs), noisy.unwrapped
            np.testing.assert_allclose(o["joint_pos"] - n.joint_positions(), 0.03, atol=1e-6)
            errors.append(o["ee_pos"] - n.ee_position())
            obs, *_ = noisy.step(np.zeros(3))
        err = np.array(errors)
        # Our rig at ~0.65 m: depth σ ≈ 6 mm at 0.5 px, lateral well under 1 mm.
        assert 1e-3 < err.std(axis=0).max() < 0.02
    finally:
        noisy.close()


# ---- pixels ----------------------------------------------------------------------------------
@pytest.mark.parametrize("size", [84, 48])
def test_pixel_observations_from_a_robosuite_camera(size: int) -> None:
    env = gym.make(LIFT, dr="none", obs_mode="pixels", image_size=size, render_mode="rgb_array")
    try:
        obs, _ = env.reset(seed=0)
        assert obs.shape == (size, size, 3) and obs.dtype == np.uint8
        assert env.observation_space.contains(obs)
        assert obs.std() > 10  # not a blank frame
        q = size // 4
        assert obs[-q:].mean() > obs[:q].mean() + 20  # upright: white table below, wall above
        for _ in range(5):
            moved, *_ = env.step(np.array([0, 0, 1.0, 0, 0, 0, -1.0]))
        assert np.abs(moved.astype(int) - obs).sum() > 0  # the arm moved in the picture
        frame = env.render()
        assert frame is not None and frame.shape == (480, 640, 3)
    finally:
        env.close()


def test_colour_dr_starts_from_the_colour_a_geom_is_drawn_in() -> None:
    """Writing each geom's shown colour into geom rgba leaves the picture unchanged, so the
    jitter is around what the camera sees (materials included), not around a grey default."""
    from sim2real.randomization.robosuite_dr import shown_rgba

    env = gym.make(LIFT, dr="none", render_mode="rgb_array", render_width=160, render_height=120)
    try:
        u = env.unwrapped
        env.reset(seed=0)
        before = env.render()
        geoms = u.targets.ids.colour_geoms
        shown = shown_rgba(u.model, geoms)
        u.model.geom_rgba[geoms] = shown
        np.testing.assert_array_equal(env.render(), before)
        shown[:, :3] = np.clip(shown[:, :3] - 0.3, 0.0, 1.0)  # white would saturate upwards
        u.model.geom_rgba[geoms] = shown
        assert np.abs(env.render().astype(int) - before).mean() > 1.0
        u.restore_nominal()
        np.testing.assert_array_equal(env.render(), before)
    finally:
        env.close()
