"""The Arm contract: one suite every backend passes (SerialArm on each emulated protocol here,
SimArm in MuJoCo in the deploy tests).

To run it against a backend, subclass ``ArmContract`` in a test module and provide two fixtures:

    arm    -> a fresh, *unconnected* Arm (an ``hardware.arm.ArmBase``) for each test
    probe  -> an ``ArmProbe``: ground truth about that backend the arm itself cannot report

From another test directory, import it by path (pytest runs with --import-mode=importlib):

    sys.path.insert(0, str(Path(__file__).parents[1] / "hardware"))
    from arm_contract import ArmContract, ArmProbe
"""

from __future__ import annotations

import itertools
import time
from dataclasses import FrozenInstanceError
from typing import Protocol

import numpy as np
import pytest

from hardware.arm import Arm, ArmBase, ArmState
from hardware.errors import NotConnectedError, SafetyError

STEP_EPS_RAD = 1e-9


class ArmProbe(Protocol):
    """What the backend really did, seen from outside the Arm."""

    def true_positions_rad(self) -> np.ndarray:
        """The joints' true angles (n_actuators,)."""

    def torque_enabled(self) -> bool:
        """True when every actuator is powered."""

    def received_targets_rad(self) -> list[np.ndarray]:
        """Every target vector the backend applied (as it decoded it), oldest first."""


def _check_received(arm: ArmBase, received: list[np.ndarray]) -> None:
    spec = arm.spec
    lo, hi = spec.actuator_lower_rad, spec.actuator_upper_rad
    for q in received:
        assert np.all(np.isfinite(q)), q
        assert np.all(q >= lo - STEP_EPS_RAD) and np.all(q <= hi + STEP_EPS_RAD), q
    for a, b in itertools.pairwise(received):
        assert np.all(np.abs(b - a) <= arm.safety.max_step_rad + STEP_EPS_RAD), (a, b)


class ArmContract:
    """Subclass and provide the ``arm`` and ``probe`` fixtures."""

    tolerance_rad = 0.06  # arrival tolerance: deadband + quantisation + lag at the end of a move

    @pytest.fixture
    def arm(self) -> ArmBase:
        raise NotImplementedError("subclasses provide an unconnected arm")

    @pytest.fixture
    def probe(self, arm: ArmBase) -> ArmProbe:
        raise NotImplementedError("subclasses provide a probe for the arm's backend")

    def test_is_an_arm(self, arm: ArmBase) -> None:
        assert isinstance(arm, Arm)
        assert arm.spec.n_actuators == len(arm.spec.actuator_names)

    def test_context_manager_connects_and_releases(self, arm: ArmBase, probe: ArmProbe) -> None:
        with arm as a:
            assert a is arm
            state = a.read_state()
            assert state.positions_rad.shape == (arm.spec.n_actuators,)
        assert not probe.torque_enabled()
        with pytest.raises(NotConnectedError):
            arm.read_state()
        with pytest.raises(NotConnectedError):
            arm.command(arm.spec.actuator_home_rad)
        arm.close()  # a second close is harmless

    def test_state_shapes_values_and_clock(self, arm: ArmBase, probe: ArmProbe) -> None:
        n = arm.spec.n_actuators
        with arm:
            states = [arm.read_state() for _ in range(3)]
        for s in states:
            assert isinstance(s, ArmState)
            assert s.positions_rad.shape == (n,)
            assert np.all(np.isfinite(s.positions_rad))
            for extra in (s.velocities_rad_s, s.loads):
                assert extra is None or extra.shape == (n,)
            with pytest.raises(ValueError):
                s.positions_rad[0] = 1.0  # read-only
            with pytest.raises(FrozenInstanceError):
                s.timestamp_s = 0.0  # type: ignore[misc]
        stamps = [s.timestamp_s for s in states]
        assert stamps == sorted(stamps)
        # at power-up the arm rests in the park pose
        assert np.allclose(
            states[-1].positions_rad, probe.true_positions_rad(), atol=self.tolerance_rad
        )

    def test_command_refused_while_torque_off(self, arm: ArmBase, probe: ArmProbe) -> None:
        with arm:
            before = len(probe.received_targets_rad())
            with pytest.raises(SafetyError, match="torque is off"):
                arm.command(arm.spec.actuator_home_rad)
            assert len(probe.received_targets_rad()) == before

    def test_wrong_shape_is_refused(self, arm: ArmBase) -> None:
        with arm:
            arm.enable()
            for bad in ([0.0, 0.0], np.zeros((2, 2)), "home", None):
                with pytest.raises(SafetyError):
                    arm.command(bad)

    def test_sent_is_what_the_backend_received(self, arm: ArmBase, probe: ArmProbe) -> None:
        with arm:
            arm.enable()
            goal = arm.spec.actuator_home_rad
            for _ in range(3):
                sent = arm.command(goal)
                assert sent.shape == (arm.spec.n_actuators,)
                received = probe.received_targets_rad()
                assert received, "the backend logged no targets"
                np.testing.assert_allclose(received[-1], sent, atol=1e-6)

    def test_limits_step_clamp_and_nonfinite(self, arm: ArmBase, probe: ArmProbe) -> None:
        spec = arm.spec
        lo, hi = spec.actuator_lower_rad, spec.actuator_upper_rad
        step = arm.safety.max_step_rad
        with arm:
            arm.enable()
            first = len(probe.received_targets_rad())
            prev = arm.last_sent_rad
            assert prev is not None
            nasty = [
                np.full(spec.n_actuators, 1e9),
                np.full(spec.n_actuators, -np.inf),
                np.full(spec.n_actuators, np.nan),
                np.array([np.nan, np.inf, -1e9, 0.3])[: spec.n_actuators],
                hi + 10.0,
            ]
            for target in nasty:
                sent = arm.command(target)
                assert np.all(sent >= lo - STEP_EPS_RAD) and np.all(sent <= hi + STEP_EPS_RAD)
                assert np.all(np.abs(sent - prev) <= step + STEP_EPS_RAD)
                nonfinite = ~np.isfinite(target)
                np.testing.assert_allclose(sent[nonfinite], prev[nonfinite], atol=1e-9)
                prev = sent
            received = probe.received_targets_rad()[first:]
            assert len(received) >= len(nasty)
            _check_received(arm, received)

    def test_moves_to_a_pose(self, arm: ArmBase, probe: ArmProbe) -> None:
        spec = arm.spec
        goal = np.clip(
            spec.actuator_home_rad + 0.2, spec.actuator_lower_rad, spec.actuator_upper_rad
        )
        with arm:
            state = arm.move_to(goal, tolerance_rad=self.tolerance_rad)
            np.testing.assert_allclose(state.positions_rad, goal, atol=self.tolerance_rad)
            # Servos without feedback report the commanded pulse: the horn may still be on its
            # way. Keep holding (the loop's rhythm, 50 Hz) until it arrives.
            for _ in range(100):
                if np.all(np.abs(probe.true_positions_rad() - goal) <= self.tolerance_rad):
                    break
                arm.hold()
                time.sleep(0.02)
            np.testing.assert_allclose(probe.true_positions_rad(), goal, atol=self.tolerance_rad)
            _check_received(arm, probe.received_targets_rad())

    def test_home(self, arm: ArmBase, probe: ArmProbe) -> None:
        with arm:
            state = arm.home()
            assert probe.torque_enabled()
            np.testing.assert_allclose(
                state.positions_rad, arm.spec.actuator_home_rad, atol=self.tolerance_rad
            )

    def test_disable_and_close_release_torque(self, arm: ArmBase, probe: ArmProbe) -> None:
        with arm:
            arm.enable()
            assert probe.torque_enabled()
            arm.disable()
            assert not probe.torque_enabled()
            with pytest.raises(SafetyError):
                arm.command(arm.spec.actuator_home_rad)
            arm.enable()
            arm.command(arm.spec.actuator_home_rad)
            assert probe.torque_enabled()
        assert not probe.torque_enabled()

    def test_an_operator_estop_is_not_cleared_by_homing(
        self, arm: ArmBase, probe: ArmProbe
    ) -> None:
        """After a watchdog or fault e-stop, home() re-enables (a simulated arm recovers for the
        next episode); after a person's, only an explicit enable() moves the arm again."""
        with arm:
            arm.home()
            arm.estop("a fault")
            arm.home()
            assert probe.torque_enabled() and arm.estop_reason is None
            arm.estop("the e-stop key", operator=True)
            with pytest.raises(SafetyError, match="e-stop latched"):
                arm.home()
            assert not probe.torque_enabled()
            arm.enable()
            arm.home()
            assert probe.torque_enabled()

    def test_estop_holds_then_releases_and_latches(self, arm: ArmBase, probe: ArmProbe) -> None:
        with arm:
            arm.enable()
            sent = arm.command(arm.spec.actuator_home_rad)
            n_before = len(probe.received_targets_rad())
            arm.estop("contract test")
            received = probe.received_targets_rad()
            assert len(received) > n_before  # the hold: the last targets went out again
            np.testing.assert_allclose(received[-1], sent, atol=1e-6)
            assert not probe.torque_enabled()
            with pytest.raises(SafetyError, match="e-stop"):
                arm.command(arm.spec.actuator_home_rad)
            arm.enable()
            arm.command(arm.spec.actuator_home_rad)
            assert probe.torque_enabled()
