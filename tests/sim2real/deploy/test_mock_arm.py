"""The mock arm in its own process: a real pty, real MuJoCo, a real child process.

Nothing here depends on a rate or a period; the deadlines are start-up and exit bounds far above
what a loaded machine needs (a stuck child fails them instead of hanging the suite).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest
from timescale import scaled  # type: ignore[import-not-found]

from hardware.errors import HardwareError
from hardware.plant import Plant
from hardware.serial_arm import SerialArm
from hardware.spec import ArmSpec
from sim2real.deploy.mock_arm import MockArmJob, MockArmProcess
from sim2real.deploy.policy_io import PolicyIO

from .children import assert_dies_with_its_host, kill_mid_deploy  # type: ignore[import-not-found]
from .conftest import pid_alive  # type: ignore[import-not-found]

EXIT_BOUND_S = scaled(60.0)


@pytest.mark.realtime
def test_the_control_channel_round_trips_and_the_pty_serves_the_arm(spec: ArmSpec) -> None:
    with MockArmProcess(MockArmJob(plant=Plant.nominal(spec), scene="pick")) as mock:
        assert mock.firmware == "Emulator" and mock.pid != os.getpid()
        # place: the child's MuJoCo puts the cube there; the truth comes back through shm
        mock.call("place", {"cube": np.array([0.16, 0.03, 0.4])})
        _, objects, grasped = mock.truth()
        np.testing.assert_allclose(objects["cube"][:2], [0.16, 0.03], atol=1e-3)
        assert grasped is False
        assert "seam_start" not in objects  # a pick scene has no seam
        # the physics keeps stepping in the child, and the cube stays on the table
        steps = mock.physics_steps()
        deadline = time.monotonic() + EXIT_BOUND_S
        while mock.physics_steps() == steps and time.monotonic() < deadline:
            time.sleep(0.01)
        assert mock.physics_steps() > steps
        np.testing.assert_allclose(mock.truth()[1]["cube"][:2], [0.16, 0.03], atol=2e-3)
        mock.call("clear")
        assert np.linalg.norm(mock.truth()[1]["cube"][:2] - [0.16, 0.03]) > 0.3
        # the host talks to the arm through the pty only, as to a real one
        with SerialArm(spec, mock.port, "s2r", timeout_s=scaled(0.5)) as arm:
            state = arm.read_state()
            np.testing.assert_allclose(
                state.positions_rad, mock.true_positions_rad(), atol=0.03
            )  # fmt: skip
        assert mock.applied("torque"), "the device saw no torque command over the pty"
        with pytest.raises(
            HardwareError, match=r"^jump failed in the mock arm process: KeyError.*valid"
        ):
            mock.call("jump")
    assert mock.pid is not None and not pid_alive(mock.pid)
    assert mock.applied("torque")  # the device's log outlives its process


def test_a_child_that_cannot_start_says_why_in_one_line(spec: ArmSpec) -> None:
    job = MockArmJob(plant=Plant.nominal(spec), scene="kitchen")
    with pytest.raises(HardwareError) as info:
        MockArmProcess(job).start()
    message = str(info.value)
    assert "kitchen" in message and "\n" not in message, message


_HOST = """
import sys
from hardware.plant import Plant
from hardware.spec import load_spec
from sim2real.deploy.mock_arm import MockArmJob, MockArmProcess
mock = MockArmProcess(MockArmJob(plant=Plant.nominal(load_spec()), scene="reach"))
mock.start()
print(mock.pid, flush=True)
sys.stdin.read()  # until killed
"""


@pytest.mark.realtime
def test_the_arm_process_dies_when_its_host_is_killed() -> None:
    assert_dies_with_its_host(_HOST, "mock arm")


@pytest.mark.realtime
def test_a_crash_of_the_arm_process_stops_the_run_in_one_line_and_keeps_the_log(
    spec: ArmSpec, reach_io: PolicyIO, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    message = kill_mid_deploy(
        spec, reach_io, tmp_path / "crash.npz", monkeypatch,
        lambda session: session.arm.emulator.pid,
    )  # fmt: skip
    assert message == "the mock arm process died (killed by SIGKILL)", message
