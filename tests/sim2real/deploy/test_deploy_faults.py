"""Faults injected into a mock deploy (the emulator on a pty, MuJoCo physics, rendered cameras,
perception in its own process): each ends in the documented safe state with the log kept and
one line saying why. The rows of the fault table in docs/hardware.md name these tests.

A fault is injected at a period (an event: the policy's own call count, through the public
``bind`` hook a privileged teacher uses), never after a wall-clock delay; the margins are the
mock's relaxed watchdogs (``MOCK``), scaled by SIM2REAL_TIME_SCALE. No assertion depends on a
rate being met."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from timescale import scaled  # type: ignore[import-not-found]

from hardware.errors import DeviceResetError, HardwareError, StallError
from hardware.spec import ArmSpec
from sim2real.deploy.loop import DeployStopError, LoopConfig
from sim2real.deploy.policy_io import PolicyIO, io_for
from sim2real.deploy.runner import DeployOptions, run_policy

from .conftest import MOCK, ik_policy  # type: ignore[import-not-found]

START_S = scaled(60.0)
# Slow as well (CI runs them after the main suite): five mock chains, ~40 s of a worker. The fast
# suite keeps each fault at the HAL, on the emulator's pty (tests/hardware/test_feedback.py: a
# jammed measured joint, a brownout under a live link), in perception (test_perception_faults.py:
# a false plate, frozen frames) and the loop's own stops on the mock chain (test_loop.py: a
# vanished port, cameras that stop; test_mock_arm.py, a crashed process).
pytestmark = [pytest.mark.realtime, pytest.mark.slow]


class FaultAt:
    """A scripted policy that injects ``fault(arm, world)`` before its ``at``-th action."""

    def __init__(
        self, policy: Callable[[Any], np.ndarray], at: int, fault: Callable[[Any, Any], None]
    ) -> None:
        self.policy, self.at, self.fault = policy, at, fault
        self.calls = 0
        self.arm: Any = None
        self.world: Any = None

    def bind(self, arm: Any, world: Any) -> Any:
        self.arm, self.world = arm, world
        return world

    def __call__(self, obs: Any) -> np.ndarray:
        self.calls += 1
        if self.calls == self.at:
            self.fault(self.arm, self.world)
        return self.policy(obs)


def _run(
    spec: ArmSpec, io: PolicyIO, policy: FaultAt, log: Path, config: LoopConfig | None = None
) -> None:
    run_policy(
        policy, io, spec, DeployOptions(**MOCK),
        config or LoopConfig(episodes=3, start_timeout_s=START_S), log_path=log,
    )  # fmt: skip


def _targets_rad(arm: Any) -> list[np.ndarray]:
    return [
        arm.calibration.from_units(np.array(e.applied)) for e in arm.emulator.applied("targets")
    ]


def test_a_brownout_mid_episode_reenables_holds_and_parks_slowly_with_the_log_kept(
    spec: ArmSpec, reach_io: PolicyIO, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    log = tmp_path / "brownout.npz"
    policy = FaultAt(ik_policy(spec, reach_io.builder, reach_io.decoder), 15,
                     lambda arm, world: arm.emulator.brownout())  # fmt: skip
    with (
        caplog.at_level(logging.WARNING),
        pytest.raises(DeviceResetError, match=r"device reset detected .* parked slowly"),
    ):
        _run(spec, reach_io, policy, log)
    assert np.load(log)["obs"].shape[0] >= 14  # the log up to the reset
    kinds = [e.kind for e in policy.arm.emulator.applied()]
    reset = kinds.index("reset")
    torque_on = [e for e in policy.arm.emulator.applied()[reset:] if e.kind == "torque"]
    assert torque_on and torque_on[0].applied[0] == 1  # switched back on, not left to fall
    after = [e for e in policy.arm.emulator.applied()[reset:] if e.kind == "targets"]
    assert after, "nothing was commanded after the reset"
    last = policy.arm.calibration.from_units(np.array(after[-1].applied))
    np.testing.assert_allclose(last, spec.actuator_park_rad, atol=0.13)  # parked
    assert any("run stopped: DeviceResetError" in r.getMessage() for r in caplog.records)


def test_a_jammed_measured_joint_mid_episode_is_held_not_dropped_with_the_log_kept(
    spec: ArmSpec, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    measured = spec.with_feedback("measured")  # potentiometers wired: a stall can be felt
    io = io_for(measured, "Sim2Real/Arm3Reach-v0")
    log = tmp_path / "stall.npz"
    policy = FaultAt(ik_policy(measured, io.builder, io.decoder), 3,
                     lambda arm, world: arm.emulator.jam("elbow"))  # fmt: skip
    with caplog.at_level(logging.WARNING), pytest.raises(StallError, match=r"^stall: elbow "):
        _run(measured, io, policy, log)
    assert np.load(log)["obs"].shape[0] >= 2
    said = [r.getMessage() for r in caplog.records]
    assert any("left holding, torque on" in m for m in said), said
    torque = [e for e in policy.arm.emulator.applied() if e.kind == "torque"]
    # never switched off while the host held the link: only the host's close lets go
    assert all(e.applied[0] == 1 for e in torque[:-1])


def test_a_false_plate_that_persists_is_rejected_then_stops_at_the_blind_limit(
    spec: ArmSpec, reach_io: PolicyIO, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The cameras see the wrist plate where the arm is not (the arm drawn turned 0.5 rad):
    every such plate is rejected by the gate and logged; the tool runs on FK until the blind
    limit ends the run, held then parked, with the log kept."""
    log = tmp_path / "ghost.npz"
    policy = FaultAt(ik_policy(spec, reach_io.builder, reach_io.decoder), 5,
                     lambda arm, world: world.cameras.ghost(0.5))  # fmt: skip
    config = LoopConfig(episodes=3, start_timeout_s=START_S, blind_limit_s=1.0)
    with (
        caplog.at_level(logging.INFO),
        pytest.raises(
            DeployStopError,
            match=r"blind: tool unseen by the cameras for .* s "
            r"mid-episode \(limit 1\.0 s\); held, then parked",
        ),  # fmt: skip
    ):
        _run(spec, reach_io, policy, log, config)
    said = [r.getMessage() for r in caplog.records]
    assert any(m.startswith("wrist plate rejected: ") for m in said), said
    data = np.load(log)
    assert data["obs"].shape[0] >= 5
    # the tool estimate stayed on the arm (FK), not on the false plate 0.5 rad away
    err = np.linalg.norm(data["ee_est_m"] - data["true_tool_m"], axis=1)
    assert np.nanmax(err[5:]) < 0.03, np.nanmax(err[5:])
    last = _targets_rad(policy.arm)[-1]
    np.testing.assert_allclose(last, spec.actuator_park_rad, atol=0.13)  # parked


def test_cameras_that_repeat_their_last_image_stop_the_run_once_the_arm_moves(
    spec: ArmSpec, reach_io: PolicyIO, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    log = tmp_path / "stuck.npz"
    policy = FaultAt(ik_policy(spec, reach_io.builder, reach_io.decoder), 3,
                     lambda arm, world: world.cameras.stick())  # fmt: skip
    with (
        caplog.at_level(logging.WARNING),
        pytest.raises(HardwareError, match=r"cameras frozen: the same image for"),
    ):
        _run(spec, reach_io, policy, log)
    assert np.load(log)["obs"].shape[0] >= 2
    assert any("run stopped: HardwareError: cameras frozen" in r.getMessage()
               for r in caplog.records)  # fmt: skip
    last = _targets_rad(policy.arm)[-1]
    np.testing.assert_allclose(last, spec.actuator_park_rad, atol=0.13)  # parked
