"""Pololu Maestro compact protocol at the byte level, CRC-7, and the emulated Maestro."""

from __future__ import annotations

import struct
from collections.abc import Callable

import serial

from hardware.emulator import Emulator
from hardware.protocols import maestro as ms
from hardware.protocols.maestro import crc7, set_target_cmd, with_crc
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
    emu = make_emulator(spec, "maestro")
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
