"""The privileged pick teacher through the deploy loop (``deploy.privileged.TruthTeacher``), and
a held cube set down before the arm homes or parks (``ControlSession.put_down``)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hardware.spec import load_spec
from sim2real.deploy.policy_io import policy_io
from sim2real.deploy.privileged import TruthTeacher
from sim2real.deploy.runner import run_policy
from sim2real.deploy.session import LoopConfig
from sim2real.deploy.worlds import CameraWorld
from sim2real.envs.pick import PickServo, lift_goal
from sim2real.errors import ConfigError
from sim2real.held_out import EvalTarget, held_out_placements

from .conftest import FAST, LOCKSTEP  # type: ignore[import-not-found]


def _teacher() -> tuple[TruthTeacher, Any, Any]:
    spec = load_spec()
    target = EvalTarget.load("pick-ppo")
    io = policy_io(spec, target.policy.meta)
    teacher = TruthTeacher(
        PickServo(io.decoder).action, io, extra=lambda view: lift_goal(view.objects["cube"])
    )
    return teacher, io, target


def test_the_teacher_picks_through_the_sim_loop_and_sets_the_cube_down() -> None:
    """Three held-out placements on the sim backend (lockstep): each ends lifted within 2 cm of
    its goal; before homing, and before the final park, the held cube goes back on the table
    (the park used to fail with it in the fingers), so the run ends parked, torque off, with no
    e-stop on the way."""
    teacher, io, target = _teacher()
    placements = tuple(held_out_placements(target, 3))
    result = run_policy(
        teacher, io, load_spec(), LOCKSTEP,
        LoopConfig(episodes=3, placements=placements, **FAST),
    )  # fmt: skip
    assert [e.success for e in result.episodes] == [True, True, True]
    assert result.stopped_early is None
    arm: Any = result.arm  # type: ignore[attr-defined]
    assert not arm.is_enabled and arm.estop_reason is None
    cube_z = float(arm.data.xpos[arm.model.body("cube").id][2])
    assert cube_z < 0.02  # on the table (its centre is 10.6-14.4 mm up), not in the fingers


def test_a_teacher_needs_a_world_that_knows_the_truth() -> None:
    teacher, _, _ = _teacher()
    with pytest.raises(ConfigError, match="needs the truth: deploy it on --backend sim or mock"):
        teacher.bind(None, CameraWorld())  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"TruthTeacher.bind\(arm, world\) first"):
        teacher(np.zeros(34))
