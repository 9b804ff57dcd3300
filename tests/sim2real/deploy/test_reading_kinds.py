"""A policy runs only on the reading kinds it was trained on, and deploy says so in one line:
at load (the policy's spec record against the arm's spec), before a port opens (the spec's kinds
against what the protocol can deliver) and at connect (the device's first state against the
spec), over a real pty with the emulated firmware."""

from __future__ import annotations

import contextlib
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hardware.emulator import Emulator
from hardware.spec import ArmSpec, load_spec
from sim2real.deploy.connection import ArmConnection
from sim2real.deploy.loop import LoopConfig
from sim2real.deploy.policy_io import io_for
from sim2real.deploy.runner import build_serial, check_protocol_readings, deploy, run_policy
from sim2real.envs.pick import HOLD_MARGIN_RAD
from sim2real.errors import ConfigError
from sim2real.export.policy import load_policy
from sim2real.policies import resolve_policy
from sim2real.runmeta import PolicyError

MEASURED = load_spec()
PWM_PATH = Path(__file__).parents[3] / "hardware" / "specs" / "arm3_mg996r_pwm.yaml"
PWM = load_spec(PWM_PATH)


@pytest.fixture
def make_emulator() -> Iterator[Callable[[ArmSpec], Emulator]]:
    made: list[Emulator] = []

    def factory(spec: ArmSpec) -> Emulator:
        emu = Emulator(spec, "s2r")
        emu.start()
        made.append(emu)
        return emu

    yield factory
    for emu in made:
        emu.stop()


def _one_line(exc: pytest.ExceptionInfo[BaseException]) -> str:
    text = str(exc.value)
    assert "\n" not in text
    return text


def test_a_policy_trained_on_measured_readings_is_refused_on_a_bare_pwm_arm() -> None:
    """The shipped reach-ppo learned from potentiometer readings; the PWM build echoes its
    commands. The fingerprints differ in the readings and the name only: the line says why."""
    meta = load_policy(resolve_policy("reach-ppo")).meta
    assert set(meta.reading_kinds().values()) == {"measured"}  # type: ignore[union-attr]
    with pytest.raises(PolicyError) as exc:
        meta.check_spec(PWM)
    text = _one_line(exc)
    assert (
        "was trained on measured joint readings; this arm's spec 'arm3-mg996r-pwm' reads "
        "base_yaw, shoulder, elbow, gripper commanded (the pulse each servo was sent: bare PWM "
        "servos): train on its spec (sim2real train --spec <its yaml>)"
    ) in text
    assert "differs in more" not in text
    meta.check_spec(MEASURED)  # the build it was trained for


def test_the_refusal_names_the_joints_that_differ_and_any_other_difference() -> None:
    meta = load_policy(resolve_policy("reach-ppo")).meta
    mixed = MEASURED.with_feedback({"gripper": "commanded"})
    with pytest.raises(PolicyError, match=r"reads gripper commanded \(the pulse") as exc:
        meta.check_spec(mixed)
    assert "base_yaw" not in _one_line(exc)
    longer = replace(PWM, links=replace(PWM.links, upper_arm_m=0.13))
    with pytest.raises(PolicyError, match="differs in more than its readings") as exc:
        meta.check_spec(longer)
    _one_line(exc)
    # a policy trained on the PWM build, on the potentiometer build: the other way round
    pwm_meta = replace(meta, spec_name=PWM.name, spec_fingerprint=PWM.fingerprint(),
                       spec=PWM.to_dict())  # fmt: skip
    pwm_meta.check_spec(PWM)
    with pytest.raises(PolicyError) as exc:
        pwm_meta.check_spec(MEASURED)
    assert "was trained on commanded joint readings; this arm's spec 'arm3-mg996r' reads " in (
        _one_line(exc)
    )
    # a fingerprint alone (or a record without a spec) says only that it differs
    with pytest.raises(PolicyError, match="not for fingerprint"):
        replace(meta, spec={}).check_spec(PWM)


def test_deploy_refuses_the_policy_before_any_backend_starts() -> None:
    opts = ArmConnection(backend="sim")
    with pytest.raises(PolicyError, match="trained on measured joint readings"):
        deploy("reach-ppo", PWM, opts, LoopConfig(episodes=1))
    res = subprocess.run(
        [sys.executable, "-m", "sim2real", "deploy", "reach-ppo", "--backend", "sim",
         "--spec", str(PWM_PATH), "--episodes", "1"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2, res.stderr
    assert res.stderr.count("\n") == 1 and "reads base_yaw, shoulder, elbow, gripper" in res.stderr


def test_a_spec_the_protocol_cannot_read_is_refused_before_a_port_opens() -> None:
    check_protocol_readings(PWM, "s2r")  # the firmware reads either kind
    check_protocol_readings(MEASURED, "feetech")
    with pytest.raises(ConfigError) as exc:
        check_protocol_readings(MEASURED, "maestro")
    text = _one_line(exc)
    assert "base_yaw (measured)" in text and "protocol 'maestro'" in text
    with pytest.raises(ConfigError, match=r"gripper \(commanded\).*'feetech'"):
        check_protocol_readings(MEASURED.with_feedback({"gripper": "commanded"}), "feetech")
    # deploy's serial builder refuses it before it opens anything (the port does not exist)
    opts = ArmConnection(backend="serial", port="/dev/null-no-such-port", protocol="maestro",
                         perception="fk")  # fmt: skip
    io = io_for(MEASURED, "Sim2Real/Arm3Reach-v0")
    with contextlib.ExitStack() as stack, pytest.raises(ConfigError, match="cannot deliver"):
        build_serial(MEASURED, io, opts, stack)


@pytest.mark.parametrize(("device", "host"), [(MEASURED, PWM), (PWM, MEASURED)])
def test_the_device_reading_other_kinds_than_the_spec_is_refused_at_connect(
    make_emulator: Callable[[ArmSpec], Emulator], device: ArmSpec, host: ArmSpec
) -> None:
    """The firmware flashed for one build, the host holding the other build's spec: the first
    state's readings byte disagrees, and the arm is closed again."""
    emu = make_emulator(device)
    opts = ArmConnection(backend="serial", port=emu.port, perception="fk")
    io = io_for(host, "Sim2Real/Arm3Reach-v0")
    with contextlib.ExitStack() as stack, pytest.raises(ConfigError) as exc:
        build_serial(host, io, opts, stack)
    text = _one_line(exc)
    kinds = ("measured", "commanded") if device is MEASURED else ("commanded", "measured")
    assert f"base_yaw reads {kinds[0]} (spec: {kinds[1]})" in text
    assert "gripper reads" in text and "use the spec of the build on the port" in text
    # the same device with its own spec connects
    with contextlib.ExitStack() as stack:
        arm, _, _ = build_serial(device, io_for(device, "Sim2Real/Arm3Reach-v0"), opts, stack)
        assert list(arm.read_state().measured_mask) == list(device.actuator_measured)


@pytest.mark.slow
def test_a_pwm_build_picks_through_the_mock_chain(tmp_path: Path) -> None:
    """The bare PWM build end to end: the emulated firmware echoes its output pulses (the check
    at connect agrees), MuJoCo grasps and lifts the cube, the cameras judge it, and the logged
    readings are the commands sent, the gripper's "shut" while the cube holds it open."""
    from tests.sim2real.deploy.conftest import pick_policy

    io = io_for(PWM, "Sim2Real/Arm3Pick-v0")
    log = tmp_path / "pick.npz"
    result = run_policy(
        pick_policy(PWM, io.builder, io.decoder), io, PWM,
        ArmConnection(backend="mock", watchdog_s=2.0),
        LoopConfig(episodes=2, start_timeout_s=60), log_path=log,
    )  # fmt: skip
    assert result.stopped_early is None
    assert max(e.figures["max_lift_m"] for e in result.episodes) > 0.03
    assert any(e.figures["grasped_ever"] for e in result.episodes)
    data = np.load(log)
    # each period reads what the last one sent, as a rule: the firmware's slew covers a clamped
    # step within the period. A read the emulator answers early (a loaded machine delays the
    # command, or both arrive together) catches the slew on its way, never past it: the echo
    # lies between what was read and what was sent since, a measured joint's droop would not.
    res = PWM.servo.resolution_rad
    joints, sent = data["joints_rad"], data["sent_rad"]
    same = data["episode"][1:] == data["episode"][:-1]
    lag = np.abs(joints[1:][same] - sent[:-1][same])
    assert np.mean(lag <= res) > 0.8, np.mean(lag <= res)
    before = np.where(same[:-1, None], sent[:-2], joints[1:-1])  # sent a period earlier
    ends = np.stack([joints[1:-1], before, sent[1:-1]])[:, same[1:]]
    read = joints[2:][same[1:]]
    assert np.all(read >= ends.min(axis=0) - res) and np.all(read <= ends.max(axis=0) + res)
    held = data["grasped"][:-1].astype(bool) & (data["sent_rad"][:-1, -1] == 0.0) & same
    # a measured gripper would read open by the cube's width; this one reads shut
    assert held.any() and np.all(np.abs(data["joints_rad"][1:, -1][held]) < HOLD_MARGIN_RAD)
