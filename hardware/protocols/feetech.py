"""Protocol 2, ``feetech``: Feetech STS bus servos (STS3215, the servos of the SO-100 arm).

Packet (byte-level spec in docs/protocols.md)::

    FF FF | ID | LEN | INSTR (or ERROR in a status reply) | PARAMS (LEN-2 bytes) | CHECKSUM

LEN = number of params + 2; CHECKSUM = ~(ID + LEN + INSTR + sum(PARAMS)) & 0xFF. STS registers
are little-endian; signed values (speed, load) are sign-magnitude. Default 1 Mbps. SYNC_WRITE to the
broadcast id 0xFE has no reply; SYNC_READ makes each listed servo answer in turn.

The 8-bit checksum catches every single-byte error but not every multi-byte one, so the driver
also reads the goal registers back in every state read and rewrites a goal that did not land.

Factory settings, and what the driver does about them on connect: every servo ships with id 1
(ids are set once, per servo, as the hardware guide says; a missing id gets a hint), 1 Mbps
(the default baud here), a 500 us return delay (``configure`` lowers it to 0, as LeRobot does,
written to EEPROM only when different) and status return level 1 (level 0 gives no status to a
WRITE: refused with a one-line fix). Only STS/SMS servos (little-endian) are supported: SCS
servos are big-endian.
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from hardware.errors import DeviceResetError, NoReplyError, ProtocolError
from hardware.joint_calibration import UnitFrame
from hardware.protocols.base import DeviceInfo, Framer, Protocol, UnitState
from hardware.spec import ArmSpec

HEADER = b"\xff\xff"
BROADCAST_ID = 0xFE
MAX_LEN = 250

# Instructions
INST_PING = 0x01
INST_READ = 0x02
INST_WRITE = 0x03
INST_REG_WRITE = 0x04
INST_ACTION = 0x05
INST_SYNC_READ = 0x82
INST_SYNC_WRITE = 0x83

# Status error bits
ERRBIT_VOLTAGE = 0x01
ERRBIT_ANGLE = 0x02
ERRBIT_OVERHEAT = 0x04
ERRBIT_OVERELE = 0x08
ERRBIT_OVERLOAD = 0x20
ERROR_BIT_NAMES = {
    ERRBIT_VOLTAGE: "input voltage",
    ERRBIT_ANGLE: "angle limit",
    ERRBIT_OVERHEAT: "overheat",
    ERRBIT_OVERELE: "over-current",
    ERRBIT_OVERLOAD: "overload",
}

# STS3215 control table (address, size)
ADDR_FIRMWARE = 0
ADDR_MODEL = 3  # 2 bytes
ADDR_ID = 5
ADDR_BAUD = 6
ADDR_RETURN_DELAY = 7  # EEPROM, 2 us per unit; factory 250 (500 us)
ADDR_STATUS_RETURN_LEVEL = 8  # EEPROM; factory 1 (a status packet for every instruction)
ADDR_MIN_LIMIT = 9  # 2 bytes, EEPROM
ADDR_MAX_LIMIT = 11  # 2 bytes, EEPROM
ADDR_TORQUE_ENABLE = 40
ADDR_ACCELERATION = 41
ADDR_GOAL_POSITION = 42  # 2 bytes
ADDR_GOAL_TIME = 44
ADDR_GOAL_SPEED = 46
ADDR_TORQUE_LIMIT = 48
ADDR_LOCK = 55
ADDR_PRESENT_POSITION = 56  # 2 bytes
ADDR_PRESENT_SPEED = 58  # 2 bytes, sign bit 15
ADDR_PRESENT_LOAD = 60  # 2 bytes, sign bit 10, 0.1 % of max torque
ADDR_PRESENT_VOLTAGE = 62
ADDR_PRESENT_TEMPERATURE = 63
ADDR_MOVING = 66
STS3215_MODEL = 777
# Factory settings of an STS3215 (Feetech's memory table; LeRobot's configure_motors says the same
# of the return delay): every servo ships as id 1 at 1 Mbps, waiting 500 us before it answers.
FACTORY_ID = 1
FACTORY_RETURN_DELAY = 250
FACTORY_STATUS_RETURN_LEVEL = 1
COUNTS_PER_REV = 4096

# One sync read covers torque enable .. temperature: 24 bytes per servo.
STATE_ADDR = ADDR_TORQUE_ENABLE
STATE_LEN = ADDR_PRESENT_TEMPERATURE + 1 - ADDR_TORQUE_ENABLE


def checksum(body: bytes | bytearray | memoryview) -> int:
    """~(ID + LEN + INSTR + PARAMS) & 0xFF over the bytes after the FF FF header."""
    return (~sum(body)) & 0xFF


def encode_packet(servo_id: int, code: int, params: bytes = b"") -> bytes:
    if not 0 <= servo_id <= 0xFE:
        raise ValueError(f"servo id {servo_id} is not in 0..254")
    body = bytes((servo_id, len(params) + 2, code)) + params
    return HEADER + body + bytes((checksum(body),))


def to_sign_magnitude(value: int, sign_bit: int) -> int:
    return (abs(value) | (1 << sign_bit)) if value < 0 else value


def from_sign_magnitude(value: int, sign_bit: int) -> int:
    mask = 1 << sign_bit
    return -(value & (mask - 1)) if value & mask else value


@dataclass(frozen=True)
class FeetechPacket:
    id: int
    code: int  # instruction (to a servo) or error bits (from a servo)
    params: bytes


class FeetechFramer(Framer):
    """Finds FF FF-headed packets; drops a byte and rescans after a bad length or checksum."""

    def __init__(self, gap_s: float = 0.010) -> None:
        super().__init__()
        self.gap_s = gap_s
        self._buf = bytearray()
        self._last_s: float | None = None

    def reset(self) -> None:
        self._buf.clear()
        self._last_s = None

    def feed(self, data: bytes, now_s: float = 0.0) -> list[Any]:
        st = self.stats
        buf = self._buf
        if buf and self._last_s is not None and now_s - self._last_s > self.gap_s + 1e-9:
            st.gap_resets += 1
            st.garbage_bytes += len(buf)
            buf.clear()
        self._last_s = now_s
        buf += data
        out: list[Any] = []
        while buf:
            i = buf.find(HEADER)
            if i < 0:
                keep = 1 if buf[-1] == 0xFF else 0
                st.garbage_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                break
            if i:
                st.garbage_bytes += i
                del buf[:i]
            if len(buf) < 4:
                break
            if buf[2] == 0xFF:  # FF FF FF: the first FF is noise
                st.garbage_bytes += 1
                del buf[:1]
                continue
            n = buf[3]
            if n < 2 or n > MAX_LEN:
                st.header_errors += 1
                del buf[:1]
                continue
            total = 4 + n
            if len(buf) < total:
                break
            if checksum(memoryview(buf)[2 : total - 1]) != buf[total - 1]:
                st.crc_errors += 1
                del buf[:1]
                continue
            out.append(FeetechPacket(buf[2], buf[4], bytes(buf[5 : total - 1])))
            st.frames += 1
            del buf[:total]
        return out


def sync_write_params(address: int, size: int, per_servo: list[tuple[int, bytes]]) -> bytes:
    body = bytes((address, size))
    for sid, data in per_servo:
        if len(data) != size:
            raise ValueError(f"servo {sid}: {len(data)} data bytes, expected {size}")
        body += bytes((sid,)) + data
    return body


def goal_packet(ids: tuple[int, ...], units: np.ndarray) -> bytes:
    """The SYNC_WRITE that sets every servo's goal position (no reply)."""
    per_servo = [
        (sid, struct.pack("<H", to_sign_magnitude(int(u), 15)))
        for sid, u in zip(ids, units, strict=True)
    ]
    params = sync_write_params(ADDR_GOAL_POSITION, 2, per_servo)
    return encode_packet(BROADCAST_ID, INST_SYNC_WRITE, params)


class FeetechProtocol(Protocol):
    """Feetech STS bus: sync-write goals, one sync-read for torque/goal/position/speed/load."""

    name = "feetech"
    default_baud = 1_000_000
    description = "Feetech STS/SMS serial bus servos (STS3215, SO-100)"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._torque_expected = False
        self._last_goal: np.ndarray | None = None
        self._reset_ids: list[int] = []
        self.last_torque: list[int] = []

    @classmethod
    def unit_frame(cls, spec: ArmSpec) -> UnitFrame:
        return UnitFrame(
            units="counts",
            unit_min=0,
            unit_max=COUNTS_PER_REV - 1,
            center_units=COUNTS_PER_REV / 2,
            units_per_rad=COUNTS_PER_REV / (2 * np.pi),
        )

    @classmethod
    def make_framer(cls) -> Framer:
        return FeetechFramer(gap_s=0.5)  # lenient: network bridges may pause mid-packet

    # ---- transactions ---------------------------------------------------------------------
    def _exchange(
        self, what: str, request: bytes, ids: tuple[int, ...], n_params: int | None
    ) -> dict[int, FeetechPacket]:
        """Send one instruction; collect one status packet per id in ``ids``."""

        def attempt() -> dict[int, FeetechPacket] | None:
            got: dict[int, FeetechPacket] = {}

            def on_frame(_t: float, p: Any) -> bool:
                if (
                    p.id in ids
                    and p.id not in got
                    and (n_params is None or len(p.params) == n_params)
                ):
                    got[p.id] = p
                else:
                    self.stats.stale_frames += 1
                return len(got) == len(ids)

            done, stale = self.link.transact(request, on_frame, self.timeout_s)
            self.stats.stale_frames += stale
            if not done:
                self.stats.timeouts += 1
                return None
            return got

        replies = self._retry(what, attempt)
        for sid, p in replies.items():
            if p.code & ~ERRBIT_ANGLE:  # an angle-limit flag alone is just a clamped goal
                self.stats.device_errors += 1
                bits = [name for bit, name in ERROR_BIT_NAMES.items() if p.code & bit]
                raise ProtocolError(f"feetech servo {sid} reports error(s): {', '.join(bits)}")
        return replies

    def _read(self, sid: int, address: int, size: int) -> bytes:
        req = encode_packet(sid, INST_READ, bytes((address, size)))
        return self._exchange(f"READ {address} from servo {sid}", req, (sid,), size)[sid].params

    def _write(self, sid: int, address: int, data: bytes) -> None:
        req = encode_packet(sid, INST_WRITE, bytes((address,)) + data)
        self._exchange(f"WRITE {address} to servo {sid}", req, (sid,), 0)

    def _sync_write(self, address: int, size: int, per_servo: list[tuple[int, bytes]]) -> None:
        self.link.write(
            encode_packet(
                BROADCAST_ID, INST_SYNC_WRITE, sync_write_params(address, size, per_servo)
            )
        )

    # ---- operations -----------------------------------------------------------------------
    def ping(self) -> DeviceInfo:
        models, delays_us = [], []
        for sid in self.ids:
            try:
                self._exchange(f"PING servo {sid}", encode_packet(sid, INST_PING), (sid,), 0)
            except NoReplyError as exc:
                raise NoReplyError(
                    f"{exc}; new Feetech servos all ship with id {FACTORY_ID}: give each servo "
                    f"its id from the spec {list(self.ids)} first (docs/hardware-guide.md)"
                ) from None
            models.append(struct.unpack("<H", self._read(sid, ADDR_MODEL, 2))[0])
            delay, level = self._read(sid, ADDR_RETURN_DELAY, 2)
            if level == 0:
                raise ProtocolError(
                    f"feetech servo {sid} has status return level 0 (no reply to WRITE); set it "
                    f"to {FACTORY_STATUS_RETURN_LEVEL}, its factory setting (docs/hardware-guide.md)"
                )
            delays_us.append(2 * delay)
        return DeviceInfo(
            protocol=self.name,
            description=(
                f"Feetech bus, servo ids {list(self.ids)}, models {models}, "
                f"return delay {delays_us} us"
            ),
            n_actuators=self.n,
        )

    def configure(
        self,
        lower_units: np.ndarray,
        upper_units: np.ndarray,
        step_units: np.ndarray,
        speed_units_per_s: np.ndarray,
    ) -> None:
        """Make the servos enforce the joint limits themselves (angle-limit registers). EEPROM
        is written only when the values differ, to spare its write cycles. The factory return
        delay (500 us per status packet, 2 ms per state read of four servos) goes to 0 the same
        way."""
        for sid, lo, hi in zip(self.ids, lower_units, upper_units, strict=True):
            cur = struct.unpack("<HH", self._read(sid, ADDR_MIN_LIMIT, 4))
            delay = self._read(sid, ADDR_RETURN_DELAY, 1)[0]
            if cur == (int(lo), int(hi)) and delay == 0:
                continue
            self._write(sid, ADDR_LOCK, b"\x00")
            if delay != 0:
                self._write(sid, ADDR_RETURN_DELAY, b"\x00")
            if cur != (int(lo), int(hi)):
                self._write(sid, ADDR_MIN_LIMIT, struct.pack("<HH", int(lo), int(hi)))
            self._write(sid, ADDR_LOCK, b"\x01")

    def read_state(self) -> UnitState:
        req = encode_packet(
            BROADCAST_ID, INST_SYNC_READ, bytes((STATE_ADDR, STATE_LEN)) + bytes(self.ids)
        )
        replies = self._exchange("SYNC_READ state", req, self.ids, STATE_LEN)
        t = time.monotonic()
        pos, goal, vel, load, torque = [], [], [], [], []
        for sid in self.ids:
            b = replies[sid].params
            torque.append(b[0])
            goal.append(from_sign_magnitude(struct.unpack_from("<H", b, 2)[0], 15))
            pos.append(from_sign_magnitude(struct.unpack_from("<H", b, 16)[0], 15))
            vel.append(from_sign_magnitude(struct.unpack_from("<H", b, 18)[0], 15))
            load.append(from_sign_magnitude(struct.unpack_from("<H", b, 20)[0], 10) / 1000.0)
        self.last_torque = torque
        if self._torque_expected:
            off = [sid for sid, tq in zip(self.ids, torque, strict=True) if tq == 0]
            if off:
                self._reset_ids = off
                self._torque_expected = False
                raise DeviceResetError(
                    f"feetech servo(s) {off} report torque off although it was enabled: they "
                    "rebooted (brown-out?); call enable() (or home) to resume"
                )
            if self._last_goal is not None and not np.array_equal(goal, self._last_goal):
                # a sync-write was lost or mangled on the wire: put the goals back
                self.stats.readback_mismatches += 1
                self._write_goals(self._last_goal)
                goal = list(self._last_goal)
        return UnitState(
            positions=np.array(pos, dtype=np.int64),
            timestamp_s=t,
            targets=np.array(goal, dtype=np.int64),
            velocities=np.array(vel, dtype=float),
            loads=np.array(load, dtype=float),
            torque_on=all(tq == 1 for tq in torque),
            measured=np.ones(self.n, dtype=bool),  # the servo's own encoder
        )

    def _write_goals(self, units: np.ndarray) -> None:
        self.link.write(goal_packet(self.ids, units))

    def write_targets(self, units: np.ndarray) -> UnitState | None:
        self._last_goal = np.asarray(units, dtype=np.int64).copy()
        self._write_goals(self._last_goal)
        return None

    def set_torque(self, on: bool, hold_units: np.ndarray | None = None) -> None:
        if on and hold_units is not None:
            self.write_targets(hold_units)
        want = 1 if on else 0
        for _ in range(self.retries + 1):
            self._sync_write(ADDR_TORQUE_ENABLE, 1, [(sid, bytes((want,))) for sid in self.ids])
            self._torque_expected = False
            self.read_state()
            if all(tq == want for tq in self.last_torque):
                self._torque_expected = on
                return
            self.stats.readback_mismatches += 1
        raise ProtocolError(
            f"feetech servos {list(self.ids)} did not switch torque {'on' if on else 'off'} "
            f"after {self.retries + 1} tries"
        )

    def forget_reset(self) -> None:
        self._reset_ids = []
