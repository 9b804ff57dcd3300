"""The arm's pixel reach as a distilled student sees it: a frame beside the arm's own readings
(``proprio``), the target on its stand (``target_stand``), a selectable success distance
(``success_threshold_m``), and the privileged teacher that labels it (``reach.ReachServo``)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import sim2real.envs as envs
from sim2real.envs.base import MAX_SUCCESS_THRESHOLD_M
from sim2real.envs.reach import ReachServo
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.model import TARGET_STAND_GEOM
from sim2real.observation import PIXELS_KEY, PROPRIO_FIELDS, PROPRIO_KEY

PROPRIO = list(PROPRIO_FIELDS)


def _pixels(**kwargs: Any) -> gym.Env[Any, Any]:
    return envs.make("reach-pixels", image_size=48, **kwargs)


# ---- proprioception beside the frame ---------------------------------------------------------
def test_proprio_observes_the_state_observations_fields_beside_the_frame_never_the_truth() -> None:
    env, state = _pixels(proprio=PROPRIO), envs.make("reach")
    try:
        space = env.observation_space
        assert isinstance(space, gym.spaces.Dict) and set(space.spaces) == {PIXELS_KEY, PROPRIO_KEY}
        assert space[PIXELS_KEY].shape == (48, 48, 3) and space[PROPRIO_KEY].shape == (9,)
        layout = {f.name: f for f in state.unwrapped.builder.layout()}  # type: ignore[attr-defined]
        obs, info = env.reset(seed=3)
        u: Any = env.unwrapped
        action = np.array([0.5, -0.25, 1.0], dtype=np.float32)
        for _ in range(3):
            assert space.contains(obs)
            assert "privileged" not in obs and "privileged_state" in info
            obs, _, _, _, info = env.step(action)
        joints = obs[PROPRIO_KEY][:3]
        np.testing.assert_allclose(obs[PROPRIO_KEY][3:6], u.commanded_rad()[:3], rtol=1e-6)
        np.testing.assert_allclose(obs[PROPRIO_KEY][6:], action)
        # servo readings, not the true angles: bias, noise and quantisation of the sensor model
        assert not np.allclose(joints, u.joint_positions(), atol=1e-7)
        np.testing.assert_allclose(joints, u.joint_positions(), atol=0.05)
        assert [layout[n].stop - layout[n].start for n in PROPRIO] == [3, 3, 3]
    finally:
        env.close()
        state.close()


def test_proprio_picks_and_orders_fields_and_the_default_stays_a_bare_image() -> None:
    env = _pixels(proprio=["prev_action", "joint_target"])
    try:
        obs, _ = env.reset(seed=0)
        obs, *_ = env.step(np.full(3, -1.0, dtype=np.float32))
        np.testing.assert_allclose(obs[PROPRIO_KEY][:3], -1.0)
        np.testing.assert_allclose(obs[PROPRIO_KEY][3:], env.unwrapped.commanded_rad()[:3])  # type: ignore[attr-defined]
    finally:
        env.close()
    assert isinstance(envs.make("reach-pixels").observation_space, gym.spaces.Box)


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"proprio": ["ee_pos"]}, UnknownNameError, "unknown proprio field 'ee_pos'; valid: "),
        ({"proprio": ["joint_pos", "joint_pos"]}, ConfigError, "must be unique"),
        ({"proprio": "joint_pos"}, ConfigError, "must be a list of field names, got 'joint_pos'"),
        ({"success_threshold_m": 0.0}, ConfigError, r"success_threshold_m must be .* got 0.0"),
        ({"success_threshold_m": MAX_SUCCESS_THRESHOLD_M * 2}, ConfigError, "got 0.1"),
        ({"success_threshold_m": True}, ConfigError, "got True"),
        ({"success_threshold_m": "2cm"}, ConfigError, "got '2cm'"),
        ({"target_stand": "yes"}, ConfigError, "target_stand must be true or false, got 'yes'"),
    ],
)
def test_bad_pixel_kwargs_fail_in_one_line_naming_the_value(
    kwargs: dict[str, Any], error: type[Exception], message: str
) -> None:
    with pytest.raises(error, match=message) as exc:
        _pixels(**kwargs)
    assert "\n" not in str(exc.value)


def test_proprio_needs_a_pixel_observation() -> None:
    with pytest.raises(ConfigError, match=r"proprio \['joint_pos'\] needs obs_mode='pixels'"):
        envs.make("reach", proprio=["joint_pos"])


@pytest.mark.filterwarnings("ignore:.*Box observation space m.* value is.*infinity")
def test_the_proprio_variant_passes_gymnasiums_and_sb3s_checkers() -> None:
    env = _pixels(proprio=PROPRIO, target_stand=True, success_threshold_m=0.02)
    try:
        gym_check_env(env.unwrapped, skip_render_check=True)
        sb3_check_env(env.unwrapped, warn=False)
    finally:
        env.close()


# ---- the target's stand and the success distance ---------------------------------------------
def test_the_stand_is_drawn_only_when_asked_and_only_in_pixels() -> None:
    plain, stand = _pixels(), _pixels(target_stand=True)
    try:
        assert TARGET_STAND_GEOM in [
            stand.unwrapped.model.geom(i).name for i in range(stand.unwrapped.model.ngeom)
        ]  # type: ignore[attr-defined]
        names = [plain.unwrapped.model.geom(i).name for i in range(plain.unwrapped.model.ngeom)]  # type: ignore[attr-defined]
        assert TARGET_STAND_GEOM not in names
        a, _ = plain.reset(seed=2)
        b, _ = stand.reset(seed=2)
        assert not np.array_equal(a, b)  # the post is in the frame
        # visual only: the same physics and target, step for step
        for _ in range(5):
            _, ra, *_, ia = plain.step(np.ones(3, dtype=np.float32))
            _, rb, *_, ib = stand.step(np.ones(3, dtype=np.float32))
            assert ra == rb and ia["distance_m"] == ib["distance_m"]
    finally:
        plain.close()
        stand.close()


def test_success_threshold_moves_success_and_the_bonus_together() -> None:
    """The same rollout judged at 1 cm (reach's own) and at 2 cm: success at the final step is
    ``distance < threshold``, and the dense reward's bonus follows the same threshold."""
    runs = {}
    for threshold in (None, 0.02):
        env = envs.make("reach", dr="none", success_threshold_m=threshold)
        teacher = ReachServo(env.unwrapped.decoder)  # type: ignore[attr-defined]
        env.reset(seed=4)
        rows = []
        for _ in range(50):
            priv = env.unwrapped.privileged_state()  # type: ignore[attr-defined]
            _, reward, _, _, info = env.step(teacher.action(priv))
            rows.append((info["distance_m"], info["is_success"], reward))
        runs[threshold] = rows
        assert env.unwrapped.success_threshold_m == (threshold or 0.01)  # type: ignore[attr-defined]
        env.close()
    assert [r[0] for r in runs[None]] == [r[0] for r in runs[0.02]]
    between = [i for i, r in enumerate(runs[None]) if 0.01 <= r[0] < 0.02]
    assert between, "the approach passes through the 1-2 cm band"
    for i in between:
        assert not runs[None][i][1] and runs[0.02][i][1]
        assert runs[0.02][i][2] == pytest.approx(runs[None][i][2] + 1.0)


# ---- the privileged teacher ---------------------------------------------------------------------
@pytest.mark.parametrize(("gain", "steer"), [(1.0, "command"), (0.4, "joints")])
def test_the_teacher_reaches_the_target_on_the_real_pixel_env_under_default_dr(
    gain: float, steer: str
) -> None:
    env = _pixels(success_threshold_m=0.02)
    teacher = ReachServo(env.unwrapped.decoder, gain, steer)  # type: ignore[attr-defined]
    final = []
    try:
        for seed in range(6):
            _, info = env.reset(seed=100 + seed)
            for _ in range(50):
                action = teacher.action(info["privileged_state"])
                assert action.dtype == np.float32 and np.all(np.abs(action) <= 1.0)
                _, _, _, trunc, info = env.step(action)
            assert trunc and info["is_success"]
            final.append(info["distance_m"])
    finally:
        env.close()
    assert max(final) < 0.01  # kinematics DR (±4 mm links, ±0.03 rad zeros) corrected away


def test_the_teacher_corrects_the_kinematic_offset_it_measures() -> None:
    """With the tool where the spec puts it, the IK aim is the target itself; a measured offset
    moves the aim by exactly that offset."""
    env = envs.make("reach", dr="none")
    try:
        u: Any = env.unwrapped
        teacher = ReachServo(u.decoder)
        env.reset(seed=0)
        priv = u.privileged_state().astype(np.float64)
        spec = u.spec_arm
        q_goal = spec.inverse_kinematics(priv[10:13])
        expect = np.clip((q_goal - priv[3:6]) / u.decoder.max_delta_rad, -1, 1)
        np.testing.assert_allclose(teacher.action(priv), expect, atol=1e-5)
        shifted = priv.copy()
        shifted[7:10] += (0.0, 0.0, 0.01)  # the tool 1 cm above where fk(q) puts it
        aim = priv[10:13] - (0.0, 0.0, 0.01)
        expect = np.clip((spec.inverse_kinematics(aim) - priv[3:6]) / 0.1, -1, 1)
        np.testing.assert_allclose(teacher.action(shifted), expect, atol=1e-4)
        np.testing.assert_allclose(
            teacher.inputs(priv), 10 * np.r_[priv[10:13] - priv[7:10], priv[7:10]], rtol=1e-5
        )
        # steering from the true joints, with a gain: the step starts from q, not the command
        servo = ReachServo(u.decoder, 0.4, "joints")
        expect = np.clip(0.4 * (q_goal - priv[:3]) / 0.1, -1, 1)
        np.testing.assert_allclose(servo.action(priv), expect, atol=1e-5)
        with pytest.raises(ConfigError, match="gain must be in \\(0, 1\\], got 0.0"):
            ReachServo(u.decoder, 0.0)
        with pytest.raises(UnknownNameError, match="unknown reach teacher steer 'tool'"):
            ReachServo(u.decoder, 1.0, "tool")
    finally:
        env.close()
