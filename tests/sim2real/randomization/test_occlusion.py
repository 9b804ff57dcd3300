"""The pick cube's dropout model: hidden near the tool, held at its last sighting, blind time
reported, and the same readings the deploy loop builds from its cube tracker."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

import sim2real.envs  # noqa: F401
from sim2real.envs.pick import BLIND_CAP_S, cube_readings, holding
from sim2real.randomization.sensing import SensorModel


def _model(radius_m: float, prob: float, dropout: float) -> SensorModel:
    m = SensorModel(3, 0.0, np.eye(3), np.zeros(3), 500.0, 0.1)
    m.configure(
        {
            "joint_noise_rad": 0.0,
            "joint_bias_rad": np.zeros(3),
            "stereo_pixel_noise_px": 0.0,
            "position_bias_m": np.zeros(3),
            "obs_delay_steps": 0,
            "point_dropout_prob": dropout,
            "occlusion_radius_m": radius_m,
            "occlusion_prob": prob,
        }
    )
    return m


def test_a_cube_in_the_gripper_is_held_at_its_last_sighting_and_counts_blind_periods() -> None:
    m, rng = _model(0.03, 1.0, 0.0), np.random.default_rng(0)
    cube = np.array([[0.15, 0.0, 0.0125]])
    far_tool = np.array([0.15, 0.0, 0.2])
    est, blind = m.occlude(cube, far_tool, cube, rng)  # first call after reset always sees
    np.testing.assert_array_equal(est, cube) and np.testing.assert_array_equal(blind, [0])
    lifted = cube + [0.0, 0.0, 0.05]
    for k in range(1, 4):  # the tool holds the cube: it rises, the estimate does not
        est, blind = m.occlude(lifted, lifted[0], lifted, rng)
        np.testing.assert_array_equal(est, cube)
        assert blind[0] == k
    est, blind = m.occlude(lifted, far_tool + 0.1, lifted, rng)  # let go, seen again
    np.testing.assert_array_equal(est, lifted) and np.testing.assert_array_equal(blind, [0])
    m.reset()
    est, blind = m.occlude(cube, cube[0], cube, rng)
    np.testing.assert_array_equal(est, cube) and np.testing.assert_array_equal(blind, [0])


def test_random_dropout_rate_matches_its_probability() -> None:
    m, rng = _model(0.0, 0.0, 0.2), np.random.default_rng(1)
    cube = np.array([[0.15, 0.0, 0.0125]])
    m.occlude(cube, np.zeros(3), cube, rng)
    hidden = sum(m.occlude(cube, np.zeros(3), cube, rng)[1][0] > 0 for _ in range(4000))
    assert 0.17 < hidden / 4000 < 0.23


def test_pick_env_reports_blind_time_while_it_holds_the_cube() -> None:
    env = gym.make("Sim2Real/Arm3Pick-v0", dr="shifted")  # occlusion certain near the tool
    u = env.unwrapped
    obs, _ = env.reset(seed=2, options={"start": "held"})
    blinds = []
    for _ in range(10):
        a = np.zeros(4, dtype=np.float32)
        a[3] = -1.0
        obs, *_ = env.step(a)
        blinds.append(float(u.builder.split(obs)["cube_blind_s"][0]))
    assert max(blinds) >= 3 * u.control_dt_s  # mostly hidden while in the fingers
    env.close()


def test_cube_readings_cap_the_blind_time() -> None:
    r = cube_readings(np.zeros(3), np.array([0.1, 0.0, 0.0]), 99.0)
    assert r["cube_blind_s"][0] == BLIND_CAP_S
    np.testing.assert_allclose(r["cube_delta"], [0.1, 0.0, 0.0])


def test_a_hidden_cube_in_holding_fingers_moves_with_the_tool_in_the_env() -> None:
    """The grasp model of the cube estimate: hidden while the servo readings say the fingers
    hold something, it is where the tool is, so goal_delta shows the lift; opened fingers
    drop that assumption and the estimate falls back to the last sighting."""
    env = gym.make("Sim2Real/Arm3Pick-v0", dr="shifted")  # occlusion certain near the tool
    u = env.unwrapped
    env.reset(seed=3, options={"start": "held", "held_height_m": 0.0})
    held = 0
    goal_deltas = []
    for k in range(12):
        a = np.zeros(4, dtype=np.float32)
        a[1] = -0.5 if k >= 2 else 0.0  # shoulder back: the tool rises
        a[3] = -1.0  # keep closed
        obs, *_ = env.step(a)
        f = u.builder.split(obs)
        if f["cube_blind_s"][0] > 0 and holding(u.spec_arm, u.commanded_rad(), f["joint_pos"]):
            held += 1
            np.testing.assert_allclose(f["cube_pos"], f["ee_pos"], atol=1e-6)
            np.testing.assert_allclose(f["cube_delta"], 0.0, atol=1e-6)
            goal_deltas.append(float(f["goal_delta"][2]))
    assert held >= 5
    assert goal_deltas[-1] < goal_deltas[0] - 0.01  # the lift shows in the goal offset
    frozen = None
    for _ in range(6):
        a = np.zeros(4, dtype=np.float32)
        a[3] = 1.0  # open: no longer commanded closed, so no grasp is assumed
        obs, *_ = env.step(a)
        f = u.builder.split(obs)
        if f["cube_blind_s"][0] > 0 and not holding(u.spec_arm, u.commanded_rad(), f["joint_pos"]):
            frozen = f["cube_pos"].copy()
            assert np.linalg.norm(frozen - f["ee_pos"]) > 0.005  # the last sighting, below
    env.close()
    assert frozen is not None


def test_the_deploy_contract_applies_the_same_grasp_model() -> None:
    from hardware.spec import load_spec
    from sim2real.envs.contract import ObjectEstimate, Percept
    from sim2real.envs.pick import PickContract

    spec = load_spec()
    c = PickContract(spec, 20.0, 50)
    rest = np.array([0.15, 0.0, 0.0125])
    c.begin(Percept(np.array([0.16, 0.0, 0.12]), {"cube": ObjectEstimate(rest, 0.0)}))
    grip = spec.gripper
    assert grip is not None
    tool = rest + (0.0, 0.0, 0.03)
    hidden = Percept(tool, {"cube": ObjectEstimate(rest, 0.4)})
    reading = np.array([0.0, 0.5, 0.5, grip.closed_rad + 0.5])  # blocked open by the cube
    closed_cmd = np.array([0.0, 0.5, 0.5, grip.closed_rad])
    c.observe_arm(reading, closed_cmd)
    r = c.readings(hidden, 5)
    np.testing.assert_allclose(r["cube_pos"], tool)
    np.testing.assert_allclose(r["goal_delta"], c.goal - tool)
    open_cmd = np.array([0.0, 0.5, 0.5, grip.open_rad])
    c.observe_arm(reading, open_cmd)  # commanded open: not a grasp
    np.testing.assert_allclose(c.readings(hidden, 6)["cube_pos"], rest)
    c.observe_arm(reading, closed_cmd)
    seen = Percept(tool, {"cube": ObjectEstimate(rest + 0.001, 0.0)})  # in sight: as measured
    np.testing.assert_allclose(c.readings(seen, 7)["cube_pos"], rest + 0.001)
