"""``sim2real arm``: every subcommand against the emulator, scripted input for the interactive
ones (as a user would type it), and one-line errors for bad input."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from hardware.emulator import Emulator
from hardware.joint_calibration import ArmCalibration, nominal_calibration, with_joints
from hardware.protocols import PROTOCOLS
from hardware.serial_arm import SerialArm
from hardware.spec import DEFAULT_SPEC_PATH, ArmSpec
from sim2real.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
ENV = dict(os.environ, PYTHONPATH=str(ROOT))


def _cli(*args: str, stdin: str = "", timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "sim2real", "arm", *args],
        input=stdin,
        capture_output=True,
        text=True,
        timeout=timeout,
        env=ENV,
        cwd=ROOT,
    )


def _one_line_error(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("sim2real arm: error: "), err
    return lines[0]


def test_emulate_serves_a_pty_until_sigterm(
    spec: ArmSpec, tmp_path: Path, spawn: Callable[..., subprocess.Popen[str]]
) -> None:
    link, log = tmp_path / "arm3", tmp_path / "log.jsonl"
    proc = spawn(
        [
            sys.executable,
            "-m",
            "sim2real",
            "arm",
            "emulate",
            "--protocol",
            "feetech",
            "--link",
            str(link),
            "--log",
            str(log),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
        cwd=ROOT,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == str(link)
        assert link.is_symlink() and os.readlink(link).startswith("/dev/pts/")
        with SerialArm(spec, str(link), protocol="feetech") as arm:
            state = arm.home()
            np.testing.assert_allclose(state.positions_rad, spec.actuator_home_rad, atol=0.06)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    assert not link.exists()
    entries = [json.loads(line) for line in log.read_text().splitlines()]
    assert any(e["kind"] == "targets" for e in entries)
    assert entries[-1]["kind"] == "torque" and set(entries[-1]["applied"]) == {0}  # off on close


def test_ping_and_home(
    spec: ArmSpec, make_emulator: Callable[..., Emulator], capsys: pytest.CaptureFixture[str]
) -> None:
    emu = make_emulator(spec, "s2r")
    assert main(["arm", "ping", "--port", emu.port, "--protocol", "s2r"]) == 0
    out = capsys.readouterr().out
    assert "arm3 firmware 1.1, protocol 2" in out and "shoulder=-0.29" in out
    assert main(["arm", "home", "--port", emu.port]) == 0
    assert "home: base_yaw=+0.0" in capsys.readouterr().out
    np.testing.assert_allclose(emu.true_positions_rad(), spec.actuator_home_rad, atol=0.06)
    assert not emu.torque_enabled().any()


def test_jog_with_scripted_input(spec: ArmSpec, make_emulator: Callable[..., Emulator]) -> None:
    emu = make_emulator(spec, "s2r")
    before = emu.true_positions_rad()
    # the pauses between lines are longer than the watchdogs: the prompt keeps them fed
    proc = _cli("jog", "--port", emu.port, stdin="elbow -0.2\nbase_yaw 0.3\nwhat\nstate\nq\n")
    assert proc.returncode == 0, proc.stderr
    assert "unknown command 'what'" in proc.stdout
    after = emu.true_positions_rad()
    assert after[2] == pytest.approx(before[2] - 0.2, abs=0.06)
    assert after[0] == pytest.approx(before[0] + 0.3, abs=0.06)
    assert not emu.applied("watchdog_hold")


@pytest.mark.parametrize("protocol", ["s2r", "feetech"])
def test_calibrate_recovers_the_true_mounting(
    spec: ArmSpec, make_emulator: Callable[..., Emulator], tmp_path: Path, protocol: str
) -> None:
    frame = PROTOCOLS[protocol].unit_frame(spec)
    nominal = nominal_calibration(spec, protocol, frame, arm_id="truth")
    k = frame.units_per_rad / 636.6198  # the same offsets in this protocol's units
    true = with_joints(
        nominal,
        # base_yaw's +-1.57 rad span nearly the whole servo range: it can only be reversed
        offsets_units=[
            frame.center_units,
            frame.center_units - 25 * k,
            frame.center_units + 10 * k,
            frame.center_units,
        ],
        directions=[-1, 1, 1, 1],
    )
    emu = make_emulator(spec, protocol, mounting=true)
    refs = [0.5, 0.5, 0.5, spec.gripper.open_rad] if spec.gripper else [0.5] * 3
    script = ""
    for i in range(spec.n_actuators):
        u0 = round(true.offset_units[i])
        u1 = round(true.to_units_float(np.eye(spec.n_actuators)[i] * refs[i])[i])
        script += f"=+\n+\n-\n={u0}\n\n={u1}\n\n"  # a typo, two nudges, then the real poses
    proc = _cli(
        "calibrate",
        "--port",
        emu.port,
        "--protocol",
        protocol,
        "--arm-id",
        "lab1",
        "--calibration-dir",
        str(tmp_path),
        stdin=script,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "[4/4] gripper" in proc.stdout
    got = ArmCalibration.load(tmp_path / "lab1.yaml")
    assert got.arm_id == "lab1" and got.protocol == protocol
    np.testing.assert_array_equal([j.direction for j in got.joints], [-1, 1, 1, 1])
    np.testing.assert_allclose(got.offset_units, np.round(true.offset_units), atol=0.5)
    # the gripper's open pose sits on the firmware's inward-rounded limit: allow 0.5 %
    np.testing.assert_allclose(got.scale_units_per_rad, true.scale_units_per_rad, rtol=5e-3)
    # with the measured calibration the host's angles are the true ones
    with SerialArm(spec, emu.port, protocol=protocol, calibration=got, push_limits=False) as arm:
        state = arm.move_to(np.array([0.2, 0.3, 0.4, 0.5]))
    np.testing.assert_allclose(emu.true_positions_rad(), [0.2, 0.3, 0.4, 0.5], atol=0.06)
    np.testing.assert_allclose(state.positions_rad, emu.true_positions_rad(), atol=0.03)


def test_calibrate_abort_writes_nothing(
    spec: ArmSpec, make_emulator: Callable[..., Emulator], tmp_path: Path
) -> None:
    emu = make_emulator(spec, "s2r")
    proc = _cli(
        "calibrate",
        "--port",
        emu.port,
        "--arm-id",
        "lab1",
        "--calibration-dir",
        str(tmp_path),
        stdin="=1500\n\nq\n",
    )
    assert proc.returncode == 2
    assert "aborted by the user; nothing was written" in _one_line_error(proc.stderr)
    assert list(tmp_path.iterdir()) == []
    proc = _cli(
        "calibrate",
        "--port",
        emu.port,
        "--arm-id",
        "lab1",
        "--calibration-dir",
        str(tmp_path),
        stdin="",
    )
    assert proc.returncode == 2 and "input ended" in _one_line_error(proc.stderr)
    assert list(tmp_path.iterdir()) == []


def test_find_port_lists_ports() -> None:
    proc = _cli("find-port")
    assert proc.returncode == 0 and proc.stdout.strip()


def test_gen_limits(tmp_path: Path) -> None:
    out = tmp_path / "limits.h"
    proc = _cli("gen-limits", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "#define ARM3_N_ACTUATORS 4" in out.read_text()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["ping", "--port", "/dev/ttyNOPE0"], "no such serial port '/dev/ttyNOPE0'"),
        (["ping", "--port", "/dev/ttyNOPE0", "--arm-id", "nobody"], "no calibration file"),
        (["emulate", "--protocol", "s2r", "--corrupt", "2"], "corrupt_rate must be a probability"),
        (["emulate", "--mounting-offset", "1,2"], "expected 4 comma-separated values"),
        (
            ["emulate", "--command-latency-ms", "-5"],
            "command_latency_s must be finite and >= 0, got -0.005",
        ),
        (
            ["emulate", "--firmware", "avr", "--protocol", "maestro"],
            "the AVR firmware speaks protocol 's2r', not 'maestro'",
        ),
        (["emulate", "--maestro-timeout-ms", "-1"], "maestro_serial_timeout_s must be finite"),
    ],
)
def test_bad_input_is_one_line(args: list[str], message: str, tmp_path: Path) -> None:
    proc = _cli(*args, "--calibration-dir", str(tmp_path)) if "--arm-id" in args else _cli(*args)
    assert proc.returncode == 2
    assert message in _one_line_error(proc.stderr)


def test_corrupt_calibration_and_bad_spec_are_one_line(
    tmp_path: Path, make_emulator: Callable[..., Emulator], spec: ArmSpec
) -> None:
    emu = make_emulator(spec, "s2r")
    bad = tmp_path / "cal.yaml"
    bad.write_text("arm_id: x\n  protocol: s2r\n")
    proc = _cli("ping", "--port", emu.port, "--calibration", str(bad))
    assert proc.returncode == 2 and "corrupt calibration YAML" in _one_line_error(proc.stderr)
    wide = tmp_path / "wide.yaml"
    wide.write_text(DEFAULT_SPEC_PATH.read_text().replace("upper_rad: 1.57", "upper_rad: 2.0", 1))
    out = tmp_path / "limits.h"
    proc = _cli("gen-limits", "--spec", str(wide), "--out", str(out))
    assert proc.returncode == 2 and "more than the servo range" in _one_line_error(proc.stderr)
    assert not out.exists()


def test_wrong_protocol_is_a_no_reply_with_a_hint(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    emu = make_emulator(spec, "s2r")
    t = time.monotonic()
    proc = _cli("ping", "--port", emu.port, "--protocol", "maestro", "--timeout-ms", "20")
    assert proc.returncode == 2
    assert "no reply from maestro device" in _one_line_error(proc.stderr)
    assert time.monotonic() - t < 10
    proc = _cli("ping", "--port", emu.port, "--protocol", "dynamixel")
    assert proc.returncode == 2 and "invalid choice: 'dynamixel'" in proc.stderr


def test_maestro_crc_is_an_option_on_both_ends(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    from hardware.emulator import EmulatorConfig

    factory = make_emulator(spec, "maestro")
    proc = _cli("ping", "--port", factory.port, "--protocol", "maestro")
    assert proc.returncode == 0, proc.stderr
    assert "CRC-7 off" in proc.stdout
    with_crc = make_emulator(spec, "maestro", EmulatorConfig(maestro_crc=True))
    proc = _cli("ping", "--port", with_crc.port, "--protocol", "maestro", "--maestro-crc")
    assert proc.returncode == 0, proc.stderr
    assert "CRC-7 on" in proc.stdout
    assert with_crc.stats()["device_crc_errors"] == 0
