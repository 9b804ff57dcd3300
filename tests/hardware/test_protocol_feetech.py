"""Feetech STS packets at the byte level, and the emulated bus answering real packets."""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pytest
import serial

from hardware.emulator import Emulator
from hardware.protocols import feetech as ft
from hardware.protocols.feetech import FeetechFramer, checksum, encode_packet
from hardware.serial_arm import SerialArm
from hardware.spec import ArmSpec


def test_packet_layout_matches_the_published_example() -> None:
    # The classic example of this packet format (Dynamixel 1.0 manual, which Feetech follows):
    # read 1 byte at 0x2B from id 1 -> FF FF 01 04 02 2B 01 CC
    assert encode_packet(1, ft.INST_READ, bytes((0x2B, 0x01))) == bytes.fromhex("ffff0104022b01cc")
    assert encode_packet(1, ft.INST_PING) == bytes.fromhex("ffff010201fb")
    assert checksum(b"\x01\x02\x00") == 0xFC


def test_sign_magnitude() -> None:
    for v, bit in ((0, 15), (1234, 15), (-1234, 15), (-1000, 10), (999, 10)):
        assert ft.from_sign_magnitude(ft.to_sign_magnitude(v, bit), bit) == v
    assert ft.to_sign_magnitude(-5, 15) == 0x8005
    assert ft.to_sign_magnitude(-5, 10) == 0x0405


def test_framer_resyncs_after_noise_and_bad_checksum() -> None:
    good = encode_packet(3, 0, struct.pack("<H", 2048))
    bad = bytearray(encode_packet(2, 0, b"\x10\x20"))
    bad[-2] ^= 0x40
    framer = FeetechFramer()
    out = framer.feed(b"\xff\xff\xff" + bytes(bad) + b"\x00\x13" + good, 0.0)
    assert [(p.id, p.params) for p in out] == [(3, struct.pack("<H", 2048))]
    assert framer.stats.crc_errors == 1
    # split across reads
    framer = FeetechFramer()
    assert framer.feed(good[:3], 0.0) == []
    assert [p.id for p in framer.feed(good[3:], 0.0)] == [3]


def test_sync_write_layout() -> None:
    params = ft.sync_write_params(ft.ADDR_GOAL_POSITION, 2, [(1, b"\x00\x08"), (2, b"\xff\x0f")])
    assert params == bytes((42, 2, 1, 0x00, 0x08, 2, 0xFF, 0x0F))


def test_emulated_bus_answers_plain_pyserial(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    emu = make_emulator(spec, "feetech")
    with serial.Serial(emu.port, 1_000_000, timeout=0.5) as port:
        ids = list(spec.actuator_ids)
        port.write(
            encode_packet(
                ft.BROADCAST_ID, ft.INST_SYNC_READ, bytes((ft.ADDR_PRESENT_POSITION, 2, *ids))
            )
        )
        framer = FeetechFramer()
        got: list[ft.FeetechPacket] = []
        while len(got) < len(ids):
            data = port.read(64)
            assert data, "the bus did not answer"
            got += framer.feed(data, 0.0)
        assert [p.id for p in got] == ids
        positions = [struct.unpack("<H", p.params)[0] for p in got]
        expected = emu.mounting.to_units(spec.actuator_park_rad)
        assert np.all(np.abs(np.array(positions) - expected) <= 2)
        # a goal outside the angle limits is clamped and flagged
        port.write(
            encode_packet(
                ids[0], ft.INST_WRITE, bytes((ft.ADDR_GOAL_POSITION,)) + struct.pack("<H", 4000)
            )
        )
        reply = FeetechFramer().feed(port.read(6), 0.0)
        assert reply and reply[0].code & ft.ERRBIT_ANGLE
        entry = emu.applied("targets")[-1]
        _, hi = emu.mounting.unit_limits(spec)
        assert entry.requested == (4000,) and entry.applied == (int(hi[0]),)


# ---- factory settings ---------------------------------------------------------------------------
def test_factory_return_delay_and_status_level_and_what_connect_does(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    emu = make_emulator(spec, "feetech")
    with serial.Serial(emu.port, 1_000_000, timeout=0.5) as port:
        port.write(ft.encode_packet(1, ft.INST_READ, bytes((ft.ADDR_RETURN_DELAY, 2))))
        reply = port.read(8)
        assert reply[5:7] == bytes((250, 1))  # 500 us, a status for every instruction
    with SerialArm(spec, emu.port, protocol="feetech", timeout_s=0.2) as arm:
        assert arm.info is not None and "return delay [500, 500, 500, 500] us" in (
            arm.info.description
        )
        # connect lowered the return delay to 0 (EEPROM, written once: lock restored)
        bus = emu._device.bus  # type: ignore[union-attr]
        for servo in bus.values():
            assert servo.regs[ft.ADDR_RETURN_DELAY] == 0 and servo.regs[ft.ADDR_LOCK] == 1
        arm.enable()
        arm.command(spec.actuator_home_rad)


def test_status_level_zero_and_missing_ids_are_one_line_fixes(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    from hardware.errors import NoReplyError, ProtocolError

    emu = make_emulator(spec, "feetech")
    emu._device.bus[2].regs[ft.ADDR_STATUS_RETURN_LEVEL] = 0  # type: ignore[union-attr]
    with pytest.raises(ProtocolError, match="servo 2 has status return level 0"):
        SerialArm(spec, emu.port, protocol="feetech", timeout_s=0.05).connect()
    # the host expects the gripper on id 7; no servo on the bus has it
    emu2 = make_emulator(spec, "feetech")
    assert spec.gripper is not None
    other = replace(spec, gripper=replace(spec.gripper, servo_id=7))
    with pytest.raises(NoReplyError, match="ship with id 1"):
        SerialArm(other, emu2.port, protocol="feetech", timeout_s=0.05).connect()
