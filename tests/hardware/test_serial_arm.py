"""SerialArm beyond the contract: clear errors for every way a port can be wrong, bounded
retries, any pyserial URL (socket:// through a real TCP bridge), calibration files."""

from __future__ import annotations

import errno
import os
import socket
import threading
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import serial
from timescale import scaled

from hardware.emulator import Emulator, EmulatorConfig, FaultConfig
from hardware.errors import CalibrationFileError, NoReplyError, PortError, SafetyError, SpecError
from hardware.joint_calibration import nominal_calibration, with_joints
from hardware.protocols.base import describe_port_error
from hardware.protocols.s2r import S2RProtocol
from hardware.serial_arm import SerialArm
from hardware.spec import ArmSpec, JointSpec


def test_missing_port(spec: ArmSpec) -> None:
    with pytest.raises(PortError, match="no such serial port '/dev/ttyNOPE0'.*find-port") as info:
        SerialArm(spec, "/dev/ttyNOPE0").connect()
    assert "\n" not in str(info.value)


def test_busy_port(spec: ArmSpec, make_emulator: Callable[..., Emulator]) -> None:
    emu = make_emulator(spec, "s2r")
    # another program holds the port
    with serial.Serial(emu.port, 115200, exclusive=True), pytest.raises(PortError, match="is busy"):
        SerialArm(spec, emu.port).connect()
    with SerialArm(spec, emu.port) as arm:  # free again
        assert arm.info is not None


def test_not_a_serial_port(spec: ArmSpec, tmp_path: Path) -> None:
    plain = tmp_path / "file"
    plain.write_text("x")
    with pytest.raises(PortError, match="is not a serial port"):
        SerialArm(spec, str(plain)).connect()


def test_permission_denied_names_the_dialout_fix(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    text = describe_port_error(
        "/dev/ttyUSB0", serial.SerialException(errno.EACCES, "could not open port")
    )
    assert "permission denied on '/dev/ttyUSB0'" in text and "dialout" in text
    if os.geteuid() == 0:
        pytest.skip("running as root: file permissions cannot deny the real port here")
    emu = make_emulator(spec, "s2r")
    os.chmod(emu.device_path, 0o000)
    with pytest.raises(PortError, match="permission denied.*dialout"):
        SerialArm(spec, emu.port).connect()


def test_spec_beyond_the_servo_range_fails_before_any_port(spec: ArmSpec) -> None:
    cal = nominal_calibration(spec, "s2r", S2RProtocol.unit_frame(spec))
    off = with_joints(cal, offsets_units=[2400.0, 1500.0, 1500.0, 1500.0])
    with pytest.raises(
        SpecError, match=r"joint base_yaw: limits .* outside the servo range \[500, 2500\] us"
    ):
        SerialArm(spec, "/dev/ttyNOPE0", calibration=off)
    joints = list(spec.joints)
    joints[0] = replace(joints[0], lower_rad=-1.8, upper_rad=1.8)
    with pytest.raises(SpecError, match="more than the servo range"):
        replace(spec, joints=tuple(joints))
    assert isinstance(joints[0], JointSpec)


def test_retries_are_bounded(spec: ArmSpec, make_emulator: Callable[..., Emulator]) -> None:
    emu = make_emulator(
        spec, "s2r", EmulatorConfig(faults=FaultConfig(drop_rate=1.0, directions="tx"))
    )
    arm = SerialArm(spec, emu.port, timeout_s=0.02, retries=2)
    with pytest.raises(NoReplyError, match="to PING after 3 tries of 20 ms"):
        arm.connect()
    assert emu.sync(timeout_s=scaled(10.0))  # every try reached the device, however late
    assert emu.stats()["device_rx_frames"] == 3  # the device heard each try; every reply was lost
    assert emu.stats()["device_duplicates"] == 2  # retries reuse the SEQ: recognised as repeats


def test_retries_ride_through_lost_replies(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    emu = make_emulator(spec, "s2r", EmulatorConfig(faults=FaultConfig(drop_rate=0.3, seed=5)))
    # 20 ms a try, 50 retries: a lost reply costs 20 ms, a loaded machine's stall (up to 1 s)
    # costs retries, never the run
    with SerialArm(spec, emu.port, timeout_s=scaled(0.02), retries=50, host_watchdog_s=None) as arm:
        arm.enable()
        for _ in range(40):
            arm.command(spec.actuator_home_rad)
        assert arm.stats()["retries"] > 0


class _TcpBridge:
    """A TCP server that forwards to a serial port: what ser2net does for a remote arm."""

    def __init__(self, port_path: str) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.address = self.server.getsockname()
        self.serial = serial.Serial(port_path, 115200, timeout=0.01)
        self.running = True
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        conn, _ = self.server.accept()
        conn.settimeout(0.01)
        with conn:
            while self.running:
                try:
                    data = conn.recv(4096)
                    if not data:
                        break
                    self.serial.write(data)
                except TimeoutError:
                    pass
                back = self.serial.read(self.serial.in_waiting or 1)
                if back:
                    conn.sendall(back)

    def close(self) -> None:
        self.running = False
        self.thread.join(timeout=2)
        self.serial.close()
        self.server.close()


@pytest.fixture
def bridge(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> Iterator[tuple[_TcpBridge, Emulator]]:
    emu = make_emulator(spec, "s2r")
    b = _TcpBridge(emu.port)
    yield b, emu
    b.close()


def test_socket_url(spec: ArmSpec, bridge: tuple[_TcpBridge, Emulator]) -> None:
    b, emu = bridge
    host, port = b.address
    with SerialArm(spec, f"socket://{host}:{port}", timeout_s=0.2) as arm:
        arm.home()
        np.testing.assert_allclose(emu.true_positions_rad(), spec.actuator_home_rad, atol=0.06)
    assert not emu.torque_enabled().any()


def test_calibration_files(
    spec: ArmSpec, make_emulator: Callable[..., Emulator], tmp_path: Path
) -> None:
    cal = nominal_calibration(spec, "s2r", S2RProtocol.unit_frame(spec), arm_id="lab1")
    path = cal.save(tmp_path / "lab1.yaml")
    emu = make_emulator(spec, "s2r")
    with SerialArm(spec, emu.port, calibration=path) as arm:
        assert arm.calibration == cal
    path.write_text("arm_id: lab1\njoints: [\n")
    with pytest.raises(CalibrationFileError, match="corrupt calibration YAML.*lab1.yaml"):
        SerialArm(spec, emu.port, calibration=path)
    feetech = nominal_calibration(
        spec, "feetech", SerialArm(spec, emu.port, "feetech").calibration.frame
    )
    with pytest.raises(CalibrationFileError, match="is for protocol feetech"):
        SerialArm(spec, emu.port, protocol="s2r", calibration=feetech)


def test_pipelined_commands_reach_the_device_once_each_in_order(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    """A pipelined command returns once its bytes are out; its reply is collected before the
    next request, and a lost frame (either way) is retransmitted then with its SEQ: through
    30 % lost frames the device applies every command exactly once, in order."""
    emu = make_emulator(spec, "s2r", EmulatorConfig(faults=FaultConfig(drop_rate=0.3, seed=7)))
    rng = np.random.default_rng(0)
    sent: list[list[int]] = []
    with SerialArm(spec, emu.port, timeout_s=0.05, retries=12, host_watchdog_s=None) as arm:
        arm.enable()
        arm.set_pipelined(True)
        assert arm.proto is not None and arm.proto.pipeline
        for i in range(20):
            target = spec.actuator_home_rad + rng.uniform(-0.01, 0.01, spec.n_actuators)
            arm.command(target)
            sent.append(arm.last_sent_units.tolist())
            if i % 4:  # and back to back: the next command collects the previous reply
                state = arm.read_state()
                assert np.all(np.isfinite(state.positions_rad))
        arm.set_pipelined(False)  # collects the last reply
        assert not arm.proto.pipeline
        stats = arm.stats()
        arm.disable()
    assert [list(e.requested) for e in emu.applied("targets")] == sent
    assert stats["retries"] > 0  # the faults did hit pipelined requests
    assert emu.stats()["device_duplicates"] > 0, (stats, emu.stats())  # recognised, not re-applied


def test_a_refused_pipelined_command_raises_at_the_next_request(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    """The device refuses targets while its torque is off; pipelined, the refusal arrives with
    the next request, which raises it (the loop then stops safely)."""
    emu = make_emulator(spec, "s2r")
    with SerialArm(spec, emu.port, timeout_s=0.2, host_watchdog_s=None) as arm:
        arm.enable()
        arm.set_pipelined(True)
        arm.command(spec.actuator_home_rad)
        arm.read_state()
        assert arm.proto is not None
        arm.proto.set_torque(False)  # behind the arm's back: the device goes limp
        arm.command(spec.actuator_home_rad)  # posted: no reply waited for
        with pytest.raises(SafetyError, match="refused SET_TARGETS.*torque"):
            arm.read_state()
        arm.set_pipelined(False)
    assert not emu.applied("targets")[1:], "a refused command was applied"
