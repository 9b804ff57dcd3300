"""The mock arm in its own process: a real pty, real MuJoCo, a real child process.

Nothing here depends on a rate or a period; the deadlines are start-up and exit bounds far above
what a loaded machine needs (a stuck child fails them instead of hanging the suite).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from timescale import scaled  # type: ignore[import-not-found]

from hardware.errors import HardwareError
from hardware.plant import Plant
from hardware.serial_arm import SerialArm
from hardware.spec import ArmSpec
from sim2real.deploy.loop import LoopConfig
from sim2real.deploy.mock_arm import MockArmJob, MockArmProcess
from sim2real.deploy.policy_io import PolicyIO
from sim2real.deploy.runner import DeployOptions, run_policy

from .conftest import MOCK, ik_policy, kill_pid, pid_alive  # type: ignore[import-not-found]

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
        with pytest.raises(HardwareError, match=r"^mock arm: jump failed: KeyError.*valid"):
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
    host = subprocess.Popen(
        [sys.executable, "-c", _HOST], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    child: int | None = None
    try:
        assert host.stdout is not None
        child = int(host.stdout.readline())
        assert pid_alive(child)
        host.kill()  # SIGKILL: no cleanup code of the host's runs
        host.wait()
        deadline = time.monotonic() + EXIT_BOUND_S
        while pid_alive(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not pid_alive(child), "the mock arm outlived its host"
    finally:
        host.kill()
        host.wait()
        kill_pid(child)


@pytest.mark.realtime
def test_a_crash_of_the_arm_process_stops_the_run_in_one_line_and_keeps_the_log(
    spec: ArmSpec, reach_io: PolicyIO, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from sim2real.deploy import session as session_mod

    log = tmp_path / "crash.npz"
    calls = {"n": 0}
    real = session_mod.ControlSession.log_period
    killed: list[int] = []

    def crash_after_10(self: session_mod.ControlSession, *a: object, **k: object) -> None:
        real(self, *a, **k)  # type: ignore[arg-type]
        calls["n"] += 1
        if calls["n"] == 10:
            pid = self.arm.emulator.pid  # type: ignore[attr-defined]
            killed.append(pid)
            os.kill(pid, signal.SIGKILL)

    monkeypatch.setattr(session_mod.ControlSession, "log_period", crash_after_10)
    try:
        with pytest.raises(HardwareError) as info:
            run_policy(
                ik_policy(spec, reach_io.builder, reach_io.decoder), reach_io, spec,
                DeployOptions(**MOCK),
                LoopConfig(episodes=2, start_timeout_s=scaled(60)), log_path=log,
            )  # fmt: skip
    finally:
        for pid in killed:
            kill_pid(pid)
    message = str(info.value)
    assert message == "the mock arm process died (killed by SIGKILL)", message
    assert np.load(log)["obs"].shape[0] >= 10
