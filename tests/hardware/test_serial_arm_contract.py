"""The Arm contract on SerialArm, once per protocol, against the emulator on a real pty."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest
from arm_contract import ArmContract, ArmProbe
from emulated import EmulatorProbe

from hardware.emulator import Emulator
from hardware.serial_arm import SerialArm
from hardware.spec import ArmSpec


class _SerialContract(ArmContract):
    protocol = "s2r"
    feedback = "measured"

    @pytest.fixture
    def emulator(self, quick_spec: ArmSpec, make_emulator: Callable[..., Emulator]) -> Emulator:
        return make_emulator(quick_spec.with_feedback(self.feedback), self.protocol)

    @pytest.fixture
    def arm(self, quick_spec: ArmSpec, emulator: Emulator) -> Iterator[SerialArm]:
        spec = quick_spec.with_feedback(self.feedback)
        arm = SerialArm(spec, emulator.port, protocol=self.protocol, timeout_s=0.1)
        yield arm
        arm.close()

    @pytest.fixture
    def probe(self, arm: SerialArm, emulator: Emulator) -> ArmProbe:
        return EmulatorProbe(emulator, arm.calibration)


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
