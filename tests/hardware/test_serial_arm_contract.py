"""The Arm contract (``hardware.testing``) on SerialArm, once per protocol, against the emulator
on a real pty.

The checks judge behaviour, not timing: the serial reply time-out and both watchdogs (host and
firmware) are wide for a loaded machine and scale with ``SIM2REAL_TIME_SCALE``, as does the time
a move may go without progress."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import replace

import pytest
from emulated import EmulatorProbe
from timescale import scaled

from hardware.emulator import Emulator
from hardware.serial_arm import SerialArm
from hardware.spec import ArmSpec
from hardware.testing import CHECKS, SETTLE_TIMEOUT_S, ArmProbe


class _SerialContract:
    protocol = "s2r"
    feedback = "measured"

    @pytest.fixture
    def contract_spec(self, quick_spec: ArmSpec) -> ArmSpec:
        """quick_spec with this feedback and a watchdog (host and firmware) a loaded machine
        does not trip between two commands; the watchdog has tests of its own."""
        safety = replace(quick_spec.safety, watchdog_timeout_s=scaled(2.0))
        return replace(quick_spec, safety=safety).with_feedback(self.feedback)

    @pytest.fixture
    def emulator(self, contract_spec: ArmSpec, make_emulator: Callable[..., Emulator]) -> Emulator:
        return make_emulator(contract_spec, self.protocol)

    @pytest.fixture
    def arm(self, contract_spec: ArmSpec, emulator: Emulator) -> Iterator[SerialArm]:
        arm = SerialArm(contract_spec, emulator.port, protocol=self.protocol, timeout_s=scaled(0.5))
        yield arm
        arm.close()

    @pytest.fixture
    def probe(self, arm: SerialArm, emulator: Emulator) -> ArmProbe:
        return EmulatorProbe(emulator, arm.calibration)

    @pytest.mark.parametrize("check", CHECKS)
    def test_contract(self, check: str, arm: SerialArm, probe: ArmProbe) -> None:
        CHECKS[check](arm, probe, settle_timeout_s=scaled(SETTLE_TIMEOUT_S))


class TestS2RContract(_SerialContract):
    protocol = "s2r"


class TestS2RPwmContract(_SerialContract):
    """The firmware on bare PWM servos: every reading is the commanded pulse."""

    protocol = "s2r"
    feedback = "commanded"


class TestFeetechContract(_SerialContract):
    protocol = "feetech"


class TestMaestroContract(_SerialContract):
    protocol = "maestro"
