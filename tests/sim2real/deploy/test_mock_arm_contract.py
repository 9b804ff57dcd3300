"""The mock arm (``--backend mock``: SerialArm on the pty of the arm's own process, its servos
driving MuJoCo physics) passes the Arm contract (``hardware.testing``) as every other backend.

One process serves every check (starting MuJoCo in a child is the slow part); each check gets a
fresh SerialArm and a probe that sees only what the device did from then on. The watchdogs, the
serial reply time-out and the time a move may go without progress are wide for a loaded machine
and scale with ``SIM2REAL_TIME_SCALE``: the checks judge behaviour, not timing.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
from timescale import scaled  # type: ignore[import-not-found]

from hardware.serial_arm import SerialArm
from hardware.spec import ArmSpec
from hardware.testing import CHECKS, SETTLE_TIMEOUT_S, ArmProbe
from sim2real.deploy.connection import ArmConnection
from sim2real.deploy.mock_arm import MockArmJob, MockArmProcess

pytestmark = pytest.mark.realtime
SYNC_TIMEOUT_S = scaled(10.0)  # a bound on the device taking in the host's bytes, not a wait


class MockProbe:
    """The device's side, over the mock process's control channel: its true joints, its torque,
    and the targets it applied since the probe was made (the process outlives each arm)."""

    def __init__(self, mock: MockArmProcess, arm: SerialArm) -> None:
        self.mock = mock
        self.arm = arm
        self.first = len(self._targets())

    def _targets(self) -> list[np.ndarray]:
        self.mock.call("sync", SYNC_TIMEOUT_S)
        ids = tuple(self.arm.spec.actuator_ids)
        entries = self.mock.applied("targets")
        assert all(e.ids == ids for e in entries), "s2r applies every actuator in one frame"
        return [self.arm.calibration.from_units(np.array(e.requested)) for e in entries]

    def true_positions_rad(self) -> np.ndarray:
        return self.mock.true_positions_rad()

    def torque_enabled(self) -> bool:
        self.mock.call("sync", SYNC_TIMEOUT_S)
        return bool(np.all(self.mock.call("torque_enabled")))

    def received_targets_rad(self) -> list[np.ndarray]:
        return self._targets()[self.first :]


@pytest.fixture(scope="module")
def connection() -> ArmConnection:
    return ArmConnection(backend="mock", watchdog_s=scaled(2.0))


@pytest.fixture(scope="module")
def mock(spec: ArmSpec, connection: ArmConnection) -> Iterator[MockArmProcess]:
    job = MockArmJob(plant=connection.plant_for(spec), scene="reach", protocol="s2r")
    with MockArmProcess(job) as process:
        yield process


@pytest.fixture
def arm(spec: ArmSpec, mock: MockArmProcess, connection: ArmConnection) -> Iterator[SerialArm]:
    relaxed = connection.relaxed_host()  # the host's watchdog and reply time-out, as deploy's
    arm = SerialArm(spec, mock.port, "s2r", **relaxed)
    yield arm
    arm.close()


@pytest.fixture
def probe(mock: MockArmProcess, arm: SerialArm) -> ArmProbe:
    return MockProbe(mock, arm)


@pytest.mark.parametrize("check", CHECKS)
def test_contract(check: str, arm: SerialArm, probe: ArmProbe) -> None:
    CHECKS[check](arm, probe, settle_timeout_s=scaled(SETTLE_TIMEOUT_S))
