"""What the tests of the runtime's child processes share: a host killed under its child, a child
killed under a running deploy. Real processes, killed whatever happens."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from timescale import scaled  # type: ignore[import-not-found]

from hardware.errors import HardwareError
from hardware.spec import ArmSpec
from sim2real.deploy.loop import LoopConfig
from sim2real.deploy.policy_io import PolicyIO
from sim2real.deploy.runner import DeployOptions, run_policy

from .conftest import MOCK, ik_policy, kill_pid, pid_alive  # type: ignore[import-not-found]

BOUND_S = scaled(60.0)  # only turns a hang into a failure


def assert_dies_with_its_host(host_source: str, what: str) -> None:
    """Run ``host_source`` (it starts a child and prints the child's pid), SIGKILL the host
    (none of its cleanup runs) and wait for the child to go."""
    host = subprocess.Popen(
        [sys.executable, "-c", host_source], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    child: int | None = None
    try:
        assert host.stdout is not None
        child = int(host.stdout.readline())
        assert pid_alive(child)
        host.kill()
        host.wait()
        deadline = time.monotonic() + BOUND_S
        while pid_alive(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not pid_alive(child), f"the {what} outlived its host"
    finally:
        host.kill()
        host.wait()
        kill_pid(child)


def kill_mid_deploy(
    spec: ArmSpec, io: PolicyIO, log: Path, monkeypatch: pytest.MonkeyPatch,
    victim: Callable[[Any], int], seen: list[Any] | None = None,
) -> str:  # fmt: skip
    """A mock deploy whose child ``victim(session)`` is SIGKILLed after 10 periods: the run's
    one-line error (the log of the periods so far is kept at ``log``). ``seen`` gets the arm's
    emulator handle, for what the device saw afterwards."""
    from sim2real.deploy import session as session_mod

    calls = {"n": 0}
    real = session_mod.ControlSession.log_period
    killed: list[int] = []

    def crash_after_10(self: session_mod.ControlSession, *a: object, **k: object) -> None:
        real(self, *a, **k)  # type: ignore[arg-type]
        calls["n"] += 1
        if calls["n"] == 10:
            pid = victim(self)
            if seen is not None:
                seen.append(self.arm.emulator)  # type: ignore[attr-defined]
            killed.append(pid)
            os.kill(pid, signal.SIGKILL)

    monkeypatch.setattr(session_mod.ControlSession, "log_period", crash_after_10)
    try:
        with pytest.raises(HardwareError) as info:
            run_policy(
                ik_policy(spec, io.builder, io.decoder), io, spec,
                DeployOptions(**MOCK),
                LoopConfig(episodes=2, start_timeout_s=scaled(60)), log_path=log,
            )  # fmt: skip
    finally:
        for pid in killed:
            kill_pid(pid)
    assert np.load(log)["obs"].shape[0] >= 10
    return str(info.value)
