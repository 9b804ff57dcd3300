"""SimArm passes the same Arm contract (``hardware.testing``) as SerialArm on every emulated
protocol."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from hardware.spec import load_spec
from hardware.testing import CHECKS, ArmProbe
from sim2real.deploy.sim_arm import SimArm


class SimProbe:
    """MuJoCo's state is the ground truth the arm itself does not report."""

    def __init__(self, arm: SimArm) -> None:
        self.arm = arm

    def true_positions_rad(self) -> np.ndarray:
        return self.arm.twin.actuator_positions(self.arm.data)

    def torque_enabled(self) -> bool:
        return self.arm.torque_on

    def received_targets_rad(self) -> list[np.ndarray]:
        return self.arm.received_targets_rad()


class TestSimArmContract:
    @pytest.fixture
    def arm(self) -> Iterator[SimArm]:
        arm = SimArm(load_spec(), clock="lockstep")
        yield arm
        arm.close()

    @pytest.fixture
    def probe(self, arm: SimArm) -> ArmProbe:
        return SimProbe(arm)

    @pytest.mark.parametrize("check", CHECKS)
    def test_contract(self, check: str, arm: SimArm, probe: ArmProbe) -> None:
        CHECKS[check](arm, probe)


def test_torque_off_lets_the_arm_sag_under_gravity() -> None:
    spec = load_spec()
    with SimArm(spec) as arm:
        arm.home()
        before = arm.read_state().positions_rad.copy()
        arm.disable()
        arm._advance(1.0)
        after = arm.read_state().positions_rad
    assert np.max(np.abs(after[1:3] - before[1:3])) > 0.1  # shoulder/elbow fell
