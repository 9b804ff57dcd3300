"""Pololu Maestro compact protocol at the byte level, CRC-7, and the emulated Maestro."""

from __future__ import annotations

import struct
from collections.abc import Callable

import numpy as np
import serial

from hardware.emulator import Emulator, EmulatorConfig
from hardware.protocols import maestro as ms
from hardware.protocols.maestro import MaestroProtocol, crc7, set_target_cmd, with_crc
from hardware.serial_arm import SerialArm
from hardware.spec import ArmSpec


def test_set_target_bytes_match_pololu_example() -> None:
    # Pololu's manual: channel 2 to 1500 us = 6000 quarter-us -> 0x84, 0x02, 0x70, 0x2E
    assert set_target_cmd(2, 6000) == bytes((0x84, 0x02, 0x70, 0x2E))
    assert ms.get_position_cmd(5) == bytes((0x90, 0x05))


def test_crc7_matches_pololu_examples() -> None:
    assert crc7(bytes((0x83, 0x01))) == 0x17  # the Maestro manual's worked example
    assert crc7(bytes((0xD1, 0x01, 0x64, 0x00))) == 0x68  # the Motoron guide's example
    assert all(crc7(bytes((b,))) < 0x80 for b in range(256))  # 7 bits: never looks like a command


def test_emulated_maestro_checks_crc_and_resyncs(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    emu = make_emulator(spec, "maestro", EmulatorConfig(maestro_crc=True))
    with serial.Serial(emu.port, 115200, timeout=0.5) as port:
        good = with_crc(set_target_cmd(0, 6400), True)
        bad = bytearray(with_crc(set_target_cmd(1, 6400), True))
        bad[-1] ^= 0x01
        port.write(bytes(bad) + bytes((0x05,)) + good)  # bad CRC, a stray data byte, a good one
        port.write(
            with_crc(ms.get_position_cmd(0), True) + with_crc(bytes((ms.CMD_GET_ERRORS,)), True)
        )
        reply = port.read(4)
        pos, errors = struct.unpack("<HH", reply)
        assert pos == 6400
        assert errors & ms.ERR_SERIAL_CRC and errors & ms.ERR_SERIAL_PROTOCOL
        applied = emu.applied("targets")
        assert [(e.ids, e.requested) for e in applied] == [
            ((0,), (6400,))
        ]  # the bad one was ignored
        # errors are cleared by reading them
        port.write(with_crc(bytes((ms.CMD_GET_ERRORS,)), True))
        assert struct.unpack("<H", port.read(2))[0] == 0
        # a target beyond the channel range is clamped to it (the Maestro's channel min/max)
        port.write(with_crc(set_target_cmd(0, 12000), True))
        emu.sync()
        assert emu.applied("targets")[-1].applied == (emu.mounting.frame.unit_max,)


def test_defaults_are_the_factory_settings(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    """A Maestro out of the box: Serial CRC off, no serial timeout. The driver and the emulator
    both default to that, so a new user's arm answers without touching the Control Center."""
    import inspect

    assert inspect.signature(MaestroProtocol.__init__).parameters["crc"].default is False
    emu = make_emulator(spec, "maestro")
    with serial.Serial(emu.port, 115200, timeout=0.5) as port:
        port.write(set_target_cmd(0, 6400) + ms.get_position_cmd(0))  # no CRC bytes
        assert struct.unpack("<H", port.read(2))[0] == 6400
        port.write(bytes((ms.CMD_GET_ERRORS,)))
        assert struct.unpack("<H", port.read(2))[0] == 0
    with SerialArm(spec, emu.port, protocol="maestro", timeout_s=0.2) as arm:
        arm.enable()
        arm.command(spec.actuator_home_rad)
        assert emu.sync() and np.all(emu.torque_enabled())
        # no serial timeout at the factory: the channels keep pulsing with no command
        assert not emu.wait_until(lambda: not np.any(emu.torque_enabled()), timeout_s=0.4)


def test_crc_on_both_sides_when_enabled(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    emu = make_emulator(spec, "maestro", EmulatorConfig(maestro_crc=True))
    with SerialArm(
        spec, emu.port, protocol="maestro", timeout_s=0.2, protocol_options={"crc": True}
    ) as arm:
        state = arm.move_to(spec.actuator_home_rad, tolerance_rad=0.02)
        np.testing.assert_allclose(state.positions_rad, spec.actuator_home_rad, atol=0.02)
    assert emu.stats()["device_crc_errors"] == 0 and emu.applied("targets")
    # a host without CRC talking to a Maestro with CRC on: every command is refused
    emu2 = make_emulator(spec, "maestro", EmulatorConfig(maestro_crc=True))
    with serial.Serial(emu2.port, 115200, timeout=0.2) as port:
        port.write(set_target_cmd(0, 6400))
        port.write(set_target_cmd(0, 6400))
        emu2.sync()
    assert emu2.applied("targets") == []
