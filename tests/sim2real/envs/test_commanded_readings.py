"""An arm of bare PWM servos in simulation (``hardware/specs/arm3_mg996r_pwm.yaml``): every
reading is the echo of what was sent, slewed as the firmware slews its output, so a dragging
joint is invisible in it; pick judges "holding" from the cameras' estimates instead of the
gripper reading, in the env's sensing and in its deploy contract alike, and the privileged
scripted pick (which reads the true gripper) still picks with it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import sim2real.envs as envs
from hardware.spec import FEEDBACK_KINDS, ArmSpec, load_spec
from sim2real.envs import fused, pick
from sim2real.envs.contract import ObjectEstimate, Percept, View
from sim2real.envs.pick import (
    GRASP_NEAR_M,
    LIFT_M,
    PickContract,
    PickServo,
    holding,
    judge_holding,
)
from sim2real.train.config import EVAL_SEED_BASE

MEASURED = load_spec()
PWM = load_spec(Path(__file__).parents[3] / "hardware" / "specs" / "arm3_mg996r_pwm.yaml")


def _field(u: Any, obs: np.ndarray, name: str) -> np.ndarray:
    f = {f.name: f for f in u.builder.layout()}[name]
    return np.asarray(obs[f.start : f.stop], dtype=np.float64)


def _quantised(u: Any, rad: np.ndarray) -> np.ndarray:
    res = u.spec_arm.servo.resolution_rad
    return (np.rint(rad / res) * res).astype(np.float32).astype(np.float64)


def test_a_pwm_arm_reads_what_it_was_sent_after_the_safety_filter() -> None:
    """DR none (no bias, no delay): each reading is the quantised command the safety filter let
    through, the gripper's included; the filter's steps are within one period's slew."""
    env = envs.make("pick", spec=PWM, dr="none", safety_filter=True)
    u: Any = env.unwrapped
    rng = np.random.default_rng(0)
    try:
        obs, _ = env.reset(seed=1)
        np.testing.assert_array_equal(_field(u, obs, "joint_pos"), _quantised(u, u._sent))
        for _ in range(40):
            obs, *_ = env.step(rng.uniform(-1, 1, 4).astype(np.float32))
            np.testing.assert_array_equal(_field(u, obs, "joint_pos"), _quantised(u, u._sent))
    finally:
        env.close()


def test_a_gripper_snapped_shut_reads_the_firmware_slew() -> None:
    """Without the host's filter a closing gripper is sent shut at once; the board's output
    pulse, which is its reading, slews there at the spec's speed (10 rad/s: 0.5 rad a period)."""
    env = envs.make("pick", spec=PWM, dr="none")
    u: Any = env.unwrapped
    try:
        obs, _ = env.reset(seed=1)
        grip = PWM.gripper
        assert grip is not None
        step = grip.max_speed_rad_s * u.control_dt_s
        seen = [float(_field(u, obs, "joint_pos")[-1])]
        for _ in range(4):
            obs, *_ = env.step(np.array([0, 0, 0, -1], dtype=np.float32))
            seen.append(float(_field(u, obs, "joint_pos")[-1]))
        want = [max(grip.open_rad - k * step, grip.closed_rad) for k in range(5)]
        # to a quantum: 0.7 rad is a half-way tie between two 1 µs steps
        np.testing.assert_allclose(seen, want, atol=PWM.servo.resolution_rad)
    finally:
        env.close()


def _drag_the_elbow(spec: ArmSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Readings, true elbow angles and sent elbow targets while the elbow is swept up against
    friction far above what the servo can overcome (a jammed horn, a stripped gear)."""
    env = envs.make("reach", spec=spec, dr="none", safety_filter=True)
    u: Any = env.unwrapped
    readings, true, sent = [], [], []
    try:
        env.reset(seed=2)
        dof = int(u.model.joint("elbow").dofadr[0])
        u.model.dof_frictionloss[dof] = 50.0  # N·m: the servo stalls at about 1
        for _ in range(10):
            obs, *_ = env.step(np.array([0, 0, 1.0], dtype=np.float32))
            readings.append(_field(u, obs, "joint_pos")[2])
            true.append(u.joint_positions()[2])
            sent.append(u._sent[2])
    finally:
        env.close()
    return np.array(readings), np.array(true), np.array(sent)


def test_a_dragging_joint_is_invisible_in_its_echo() -> None:
    """The PWM arm reads the command, 1 rad ahead of a joint that has not moved; the arm with
    potentiometers reads the joint where it is."""
    reading, true, sent = _drag_the_elbow(PWM)
    assert sent[-1] - true[-1] > 0.8  # the joint lags the command by most of the sweep
    np.testing.assert_allclose(reading, sent, atol=1e-3)
    m_reading, m_true, m_sent = _drag_the_elbow(MEASURED)
    np.testing.assert_allclose(m_reading, m_true, atol=1e-3)
    assert m_sent[-1] - m_reading[-1] > 0.8


def test_the_scripted_pick_picks_on_a_pwm_arm_and_the_estimates_follow_the_cube() -> None:
    """``PickServo`` reads the true gripper (``privileged_state``), so it still teaches. The
    policy's gripper reading is its closed command while a cube holds the fingers open, so it
    cannot say "holding" (``pick.holding``); the env judges it from the estimates, and the
    observed cube, out of sight in the fingers, is lifted with the tool."""
    env = envs.make("pick", spec=PWM, safety_filter=True)
    u: Any = env.unwrapped
    teacher = PickServo(u.decoder)
    blind_ends = 0
    grip = PWM.gripper
    assert grip is not None
    try:
        for j in range(8):
            obs, _ = env.reset(seed=EVAL_SEED_BASE + j)
            rest_z = u.task.rest_z_m
            for _ in range(u.max_episode_steps):
                obs, _, _, _, info = env.step(teacher.action(u.privileged_state()))
            assert info["is_success"], f"held-out episode {j} failed"
            reading = _field(u, obs, "joint_pos")
            assert reading[-1] == pytest.approx(grip.closed_rad, abs=1e-6)  # reads its command
            assert u.gripper_angle_rad() > 0.3  # while the cube holds the fingers open
            assert not holding(PWM, u.commanded_rad(), reading)
            cube_est, cube = _field(u, obs, "cube_pos"), u.task.cube_position(u)
            assert cube_est[2] > rest_z + LIFT_M - 0.03  # the estimate was lifted too
            assert np.linalg.norm(cube_est - cube) < 0.02
            blind_ends += _field(u, obs, "cube_blind_s")[0] > 0
    finally:
        env.close()
    assert blind_ends >= 3  # most ends: the cube out of sight, carried by the grasp judgement


def test_every_reading_kind_has_a_grasp_rule_in_python_and_compiled() -> None:
    assert set(pick.HOLD_RULES) == set(FEEDBACK_KINDS) == set(fused.HOLD_RULES)


def test_judge_holding_follows_the_gripper_reading_kind() -> None:
    """The same numbers: a measured gripper that reads closed holds nothing; one that reads
    its command is judged from where the cube is seen."""
    cmd = np.array([0.0, 0.3, 0.5, 0.0])  # closed
    closed, open_ = cmd.copy(), np.array([0.0, 0.3, 0.5, 0.5])
    tool, cube = np.array([0.15, 0.0, 0.02]), np.array([0.15, 0.005, 0.0125])
    far = cube + (0.0, 0.0, -0.05)
    assert not judge_holding(MEASURED, cmd, closed, tool, cube, 0.0, False)
    assert judge_holding(MEASURED, cmd, open_, tool, far, 0.0, False)  # blocked: it feels it
    assert judge_holding(PWM, cmd, closed, tool, cube, 0.0, False)  # at the tool after the close
    assert not judge_holding(PWM, cmd, open_, tool, cube, 0.0, False)  # still slewing shut
    assert not judge_holding(PWM, cmd, closed, tool, far, 0.0, False)  # seen away from the tool
    assert judge_holding(PWM, cmd, closed, tool, far, 0.1, True)  # hidden in holding fingers
    assert not judge_holding(PWM, cmd, closed, tool, far, 0.1, False)
    opened = np.array([0.0, 0.3, 0.5, 1.2])
    assert not judge_holding(PWM, opened, opened, tool, cube, 0.1, True)  # let go


def _percept(tool: np.ndarray, cube: np.ndarray, blind_s: float = 0.0) -> Percept:
    return Percept(tool, {"cube": ObjectEstimate(cube, blind_s)})


def test_the_contract_judges_a_pwm_gripper_from_the_estimates() -> None:
    """Deploy's side on a real PWM arm (no truth): close at the cube, lift with the cube hidden
    in the fingers; the observation, the shaping, the score and the put-down all count it held.
    A close beside the cube counts until the lift leaves the cube in sight on the table."""
    rest = np.array([0.15, 0.0, 0.0125])
    opened = np.array([0.0, 0.3, 0.5, 1.2])
    shut = np.array([0.0, 0.3, 0.5, 0.0])
    c = PickContract(PWM, 20.0, 50)
    c.begin(_percept(rest + (0, 0, 0.05), rest))
    # the approach: open, the cube seen below
    c.observe_arm(opened, opened)
    assert np.allclose(c.readings(_percept(rest + (0, 0, 0.04), rest), 0)["cube_pos"], rest)
    # the close at the cube: the echo reads shut, the cube is seen at the tool
    tool = rest + (0.0, 0.004, 0.002)
    c.observe_arm(shut, shut)
    r = c.readings(_percept(tool, rest), 1)
    assert np.allclose(r["cube_pos"], rest)
    assert c.shaping() == pytest.approx(-2.0 * 0.004472135955 + 0.5, abs=1e-6)
    # the lift: the fingers hide the cube, its last sighting stays on the table
    lifted = tool + (0.0, 0.0, LIFT_M)
    c.observe_arm(shut, shut)
    r = c.readings(_percept(lifted, rest, 0.6), 2)
    np.testing.assert_allclose(r["cube_pos"], lifted)
    np.testing.assert_allclose(r["goal_delta"], c.goal - lifted)
    assert c.put_down(shut, shut) is not None  # it holds something to set down
    view = View(lifted, {"cube": rest}, shut, truth=False, blind_s={"cube": 0.6},
                commanded_rad=shut)  # fmt: skip
    for step in range(3):  # the first judged period latches the rest; the grasp carries over
        first = View(tool, {"cube": rest}, shut, False, blind_s={"cube": 0.0}, commanded_rad=shut)
        assert c.score(first if step == 0 else view, step) is None
    out = c.outcome()
    assert out.success and out.figures["grasped"] and out.figures["lift_m"] > 0.05

    # an empty close 1.5 cm beside the cube: held while the cube is at the tool, not once the
    # lift shows it on the table
    e = PickContract(PWM, 20.0, 50)
    e.begin(_percept(rest + (0, 0, 0.05), rest))
    beside = rest + (0.0, 0.015, 0.0)
    e.observe_arm(shut, shut)
    e.readings(_percept(beside, rest), 0)
    assert e.put_down(shut, shut) is not None
    up = beside + (0.0, 0.0, 0.05)
    e.observe_arm(shut, shut)
    r = e.readings(_percept(up, rest, 0.0), 1)
    np.testing.assert_allclose(r["cube_pos"], rest)
    assert e.put_down(shut, shut) is None
    assert np.linalg.norm(up - rest) > GRASP_NEAR_M


def test_a_pwm_grasp_is_judged_against_the_tool_when_the_cube_was_seen() -> None:
    """Cameras see the cube a few frames late; the tool comes from this period's readings. Mid
    lift the cube in the fingers is seen where the tool was 0.1 s ago, 2.5 cm below the tool
    now: judged against the tool at the cube's capture time it stays held (on the mock arm the
    other comparison let 12 of 100 lifts go), and a cube left on the table is still seen left."""
    rest = np.array([0.15, 0.0, 0.0125])
    shut = np.array([0.0, 0.3, 0.5, 0.0])
    grasp_tool = rest + (0.0, 0.0, 0.002)
    c = PickContract(PWM, 20.0, 50)
    c.begin(_percept(rest + (0, 0, 0.05), rest))
    c.observe_arm(shut, shut)
    c.readings(_percept(grasp_tool, rest), 0)
    tool_now = grasp_tool + (0.0, 0.0, 0.03)
    seen_then = grasp_tool + (0.0, 0.0, 0.005)  # the cube in the fingers, 0.1 s ago
    late = Percept(tool_now, {"cube": ObjectEstimate(seen_then, 0.0, tool_then_m=seen_then)})
    c.observe_arm(shut, shut)
    r = c.readings(late, 1)
    np.testing.assert_allclose(r["cube_pos"], tool_now)  # held and carried: with the tool
    assert c.put_down(shut, shut) is not None
    # without the capture-time tool the same numbers read "dropped"
    d = PickContract(PWM, 20.0, 50)
    d.begin(_percept(rest + (0, 0, 0.05), rest))
    d.observe_arm(shut, shut)
    d.readings(_percept(grasp_tool, rest), 0)
    d.observe_arm(shut, shut)
    np.testing.assert_allclose(d.readings(_percept(tool_now, seen_then), 1)["cube_pos"], seen_then)
    # a cube left on the table is seen there while the tool, then as now, rose away from it
    left = Percept(tool_now, {"cube": ObjectEstimate(rest, 0.0, tool_then_m=seen_then + 0.01)})
    e = PickContract(PWM, 20.0, 50)
    e.begin(_percept(rest + (0, 0, 0.05), rest))
    e.observe_arm(shut, shut)
    e.readings(_percept(grasp_tool, rest), 0)
    e.observe_arm(shut, shut)
    np.testing.assert_allclose(e.readings(left, 1)["cube_pos"], rest)
    assert e.put_down(shut, shut) is None
