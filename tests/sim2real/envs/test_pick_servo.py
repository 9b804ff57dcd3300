"""The privileged pick teacher and what it reads: ``pick.PickServo`` on the env's truth."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import sim2real.envs as envs
from sim2real.envs.base import privileged_true_size
from sim2real.envs.pick import PICK_PHASES, PickServo
from sim2real.errors import ConfigError
from sim2real.observation import ActionDecoder
from sim2real.train.config import EVAL_SEED_BASE


def test_the_privileged_state_carries_what_was_sent_and_the_lift_goal() -> None:
    env = envs.make("pick", safety_filter=True)
    u: Any = env.unwrapped
    try:
        env.reset(seed=3)
        env.step(np.array([0.0, 0.0, 0.0, -1.0], dtype=np.float32))  # snap shut: the clamp holds
        p = u.privileged_state()
        n_true = privileged_true_size(u.spec_arm, u.task)
        assert len(p) == n_true + u.builder.size
        sent, goal = p[n_true - 7 : n_true - 3], p[n_true - 3 : n_true]
        np.testing.assert_allclose(sent, u._sent, rtol=1e-6)
        np.testing.assert_allclose(goal, u.task.goal_m, rtol=1e-6)
        # the decoded target is "closed"; what reached the servo is one clamp step from open
        assert u.commanded_rad()[-1] == pytest.approx(0.0)
        assert sent[-1] == pytest.approx(u.spec_arm.gripper.open_rad - 0.25, abs=1e-6)
    finally:
        env.close()


def test_the_teacher_picks_held_out_cubes() -> None:
    """Ten held-out placements, DR default: every one ends lifted within 2 cm of the goal
    (``bench/pick_servo.py`` measures 200 of 200)."""
    env = envs.make("pick", safety_filter=True)
    u: Any = env.unwrapped
    teacher = PickServo(u.decoder)
    phases: set[str] = set()
    try:
        for j in range(10):
            env.reset(seed=EVAL_SEED_BASE + j)
            for _ in range(u.max_episode_steps):
                phases.add(teacher.decide(u.privileged_state())[0])
                _, _, _, _, info = env.step(teacher.action(u.privileged_state()))
            assert info["is_success"], f"held-out episode {j} failed"
    finally:
        env.close()
    assert phases == set(PICK_PHASES)


def test_the_teacher_refuses_what_it_cannot_read_in_one_line() -> None:
    env = envs.make("pick")
    u: Any = env.unwrapped
    try:
        env.reset(seed=0)
        teacher = PickServo(u.decoder)
        with pytest.raises(ConfigError, match=r"privileged state of 10 values is not pick's"):
            teacher.action(u.privileged_state()[:10])
        reach = ActionDecoder(u.spec_arm, use_gripper=False)
        with pytest.raises(ConfigError, match="needs 3 joints and a gripper in the action"):
            PickServo(reach)
    finally:
        env.close()


def test_a_cube_carried_in_the_fingers_is_not_where_a_stray_sighting_puts_it() -> None:
    """``cube_estimate``: hidden in holding fingers, the cube is at the tool; once carried so, a
    sighting far from the tool while still holding is not it (a misfit of the half-hidden cube);
    one near the tool is; before any carry (a gripper still closing in empty air reads "open"),
    a sighting on the table is where the cube is."""
    from sim2real.envs.pick import HELD_AWAY_M, cube_estimate

    tool = np.array([0.15, 0.02, 0.08])
    far = tool - (0.0, 0.0, 2 * HELD_AWAY_M)
    near = tool + (0.0, 0.005, 0.0)

    def check(got: tuple[np.ndarray, bool], want: np.ndarray, carried: bool) -> None:
        np.testing.assert_array_equal(got[0], want)
        assert got[1] is carried

    check(cube_estimate(far, tool, 0.3, True), tool, True)  # hidden in holding fingers
    check(cube_estimate(far, tool, 0.0, True, carried=True), tool, True)  # a stray sighting
    check(cube_estimate(near, tool, 0.0, True, carried=True), near, True)  # seen in the fingers
    check(cube_estimate(near, tool, 0.0, True, carried=False), near, True)  # just grasped
    check(cube_estimate(far, tool, 0.0, True, carried=False), far, False)  # closing in the air
    check(cube_estimate(far, tool, 0.0, False, carried=True), far, False)  # let go
