"""Protocol 1, ``s2r``: the framed binary protocol of our own firmware (hardware/firmware/arm3).

Frame (all multi-byte fields little-endian; byte-level spec in docs/protocols.md)::

    A5 5A | LEN | ~LEN | SEQ | TYPE | PAYLOAD (LEN bytes) | CRC16 lo | CRC16 hi

CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) over LEN..PAYLOAD. ``~LEN`` protects the length
byte on its own, so a corrupted length is caught at once instead of swallowing the next frame.
The receiver drops one byte and rescans after any header or CRC failure, so a frame embedded in
garbage is still found. Replies echo SEQ, with TYPE = request | 0x80, or 0xFF for an error.

The same framer and codecs run on the device side (the emulator's firmware model), and
``firmware/arm3/src`` implements them again in C++; tests feed identical bytes to both.
"""

from __future__ import annotations

import binascii
import contextlib
import struct
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from hardware.errors import DeviceResetError, HardwareError, ProtocolError, SafetyError
from hardware.joint_calibration import UnitFrame
from hardware.protocols.base import DeviceInfo, Framer, Protocol, UnitState
from hardware.spec import ArmSpec

SYNC = b"\xa5\x5a"
MAX_PAYLOAD = 64
HEADER_LEN = 6  # sync(2) len(1) ~len(1) seq(1) type(1)
OVERHEAD = HEADER_LEN + 2  # + crc16
# 2: STATE carries a readings byte (bit i: actuator i's position is measured), and TORQUE 1 may
# carry the pulses to start servos without a potentiometer from. PONG kept its layout, so a host
# of either version reads the other's version number and stops with one line.
PROTO_VERSION = 2
FW_VERSION = (1, 1)
GAP_MS = 10  # device side: a partial frame older than this is abandoned
HOST_GAP_S = 0.5  # host side: links over a network may pause mid-frame

# Request types; the reply type is request | REPLY, or ERROR.
PING = 0x01
SET_TARGETS = 0x02
READ_STATE = 0x03
SET_LIMITS = 0x04
TORQUE = 0x05
HEARTBEAT = 0x06
GET_STATS = 0x07
REPLY = 0x80
ERROR = 0xFF

MESSAGE_NAMES: dict[int, str] = {
    PING: "PING",
    SET_TARGETS: "SET_TARGETS",
    READ_STATE: "READ_STATE",
    SET_LIMITS: "SET_LIMITS",
    TORQUE: "TORQUE",
    HEARTBEAT: "HEARTBEAT",
    GET_STATS: "GET_STATS",
}

# Error codes carried by an ERROR reply: code u8, offending request type u8.
ERR_BAD_LENGTH = 1
ERR_UNKNOWN_TYPE = 2
ERR_TORQUE_OFF = 3
ERR_LIMIT_RANGE = 4
ERR_BAD_VALUE = 5
ERROR_NAMES: dict[int, str] = {
    ERR_BAD_LENGTH: "payload length does not fit the message type",
    ERR_UNKNOWN_TYPE: "unknown message type",
    ERR_TORQUE_OFF: "torque is off (the device watchdog detached the servos, or it rebooted)",
    ERR_LIMIT_RANGE: "limits outside the firmware's compiled limits (it only tightens them)",
    ERR_BAD_VALUE: "a value is out of range",
}

# STATE flags
FLAG_TORQUE_ON = 0x01
FLAG_WATCHDOG_HOLD = 0x02
FLAG_CLAMPED = 0x04
FLAG_CUSTOM_LIMITS = 0x08

STATS_FIELDS = (
    "rx_frames",
    "crc_errors",
    "header_errors",
    "garbage_bytes",
    "gap_resets",
    "watchdog_trips",
    "clamps",
    "duplicates",
)


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final xor."""
    return binascii.crc_hqx(bytes(data), 0xFFFF)


def encode_frame(seq: int, msg_type: int, payload: bytes = b"") -> bytes:
    """One complete frame, ready for the wire."""
    n = len(payload)
    if n > MAX_PAYLOAD:
        raise ValueError(f"payload of {n} bytes exceeds the maximum {MAX_PAYLOAD}")
    body = bytes((n, (~n) & 0xFF, seq & 0xFF, msg_type & 0xFF)) + payload
    crc = crc16(body)
    return SYNC + body + bytes((crc & 0xFF, crc >> 8))


@dataclass(frozen=True)
class S2RFrame:
    seq: int
    type: int
    payload: bytes
    crc: int  # the frame's own CRC: with seq it identifies a retransmission


class S2RFramer(Framer):
    """Finds frames in a byte stream; drops one byte and rescans after any failure."""

    def __init__(self, gap_s: float = GAP_MS / 1000.0) -> None:
        super().__init__()
        self.gap_s = gap_s
        self._buf = bytearray()
        self._last_s: float | None = None

    def reset(self) -> None:
        self._buf.clear()
        self._last_s = None

    @property
    def pending(self) -> int:
        return len(self._buf)

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
            i = buf.find(SYNC)
            if i < 0:
                keep = 1 if buf[-1] == SYNC[0] else 0
                st.garbage_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                break
            if i:
                st.garbage_bytes += i
                del buf[:i]
            if len(buf) < 4:
                break
            n = buf[2]
            if n > MAX_PAYLOAD or buf[3] != (~n) & 0xFF:
                st.header_errors += 1
                del buf[:1]
                continue
            total = OVERHEAD + n
            if len(buf) < total:
                break
            got = buf[HEADER_LEN + n] | (buf[HEADER_LEN + n + 1] << 8)
            if crc16(memoryview(buf)[2 : HEADER_LEN + n]) != got:
                st.crc_errors += 1
                del buf[:1]
                continue
            out.append(S2RFrame(buf[4], buf[5], bytes(buf[HEADER_LEN : HEADER_LEN + n]), got))
            st.frames += 1
            del buf[:total]
        return out


# ---- payload codecs (shared by host, emulator and tests) ----------------------------------
@dataclass(frozen=True)
class PongPayload:
    proto_version: int
    fw_major: int
    fw_minor: int
    n_actuators: int
    boot_id: int
    limits_crc: int
    watchdog_ms: int

    _FMT: ClassVar[str] = "<BBBBHHH"

    def encode(self) -> bytes:
        return struct.pack(
            self._FMT,
            self.proto_version,
            self.fw_major,
            self.fw_minor,
            self.n_actuators,
            self.boot_id,
            self.limits_crc,
            self.watchdog_ms,
        )

    @classmethod
    def decode(cls, payload: bytes) -> PongPayload:
        if len(payload) != struct.calcsize(cls._FMT):
            raise ProtocolError(f"PONG payload has {len(payload)} bytes, expected 10")
        return cls(*struct.unpack(cls._FMT, payload))


@dataclass(frozen=True)
class StatePayload:
    flags: int
    boot_id: int
    positions: tuple[int, ...]  # µs: the pot where bit i of ``measured`` is set, else the output
    targets: tuple[int, ...]  # µs, the firmware's current (clamped) targets
    measured: int = 0  # bit i: actuator i's position is measured (a potentiometer)

    def encode(self) -> bytes:
        n = len(self.positions)
        return struct.pack(
            f"<BHB{n}H{n}H", self.flags, self.boot_id, self.measured, *self.positions, *self.targets
        )

    @classmethod
    def decode(cls, payload: bytes, n: int) -> StatePayload:
        if len(payload) != 4 + 4 * n:
            raise ProtocolError(
                f"STATE payload has {len(payload)} bytes, expected {4 + 4 * n} for {n} actuators "
                f"(protocol {PROTO_VERSION})"
            )
        vals = struct.unpack(f"<BHB{n}H{n}H", payload)
        return cls(vals[0], vals[1], tuple(vals[3 : 3 + n]), tuple(vals[3 + n :]), vals[2])

    def measured_array(self) -> np.ndarray:
        """(n,) bool: which positions are measured."""
        return np.array([bool(self.measured >> i & 1) for i in range(len(self.positions))])


def encode_torque(on: bool, start_units: np.ndarray | Sequence[int] | None = None) -> bytes:
    """TORQUE payload: 0 or 1, and with 1 optionally the pulses (µs) to start the servos without a
    potentiometer from (where the host last sent them), so torque-on does not snap them."""
    if start_units is None or not on:
        return bytes((1 if on else 0,))
    return b"\x01" + encode_targets(start_units)


def encode_targets(units: np.ndarray | Sequence[int]) -> bytes:
    vals = [int(u) for u in units]
    return struct.pack(f"<{len(vals)}H", *vals)


def decode_targets(payload: bytes) -> tuple[int, ...]:
    if len(payload) % 2:
        raise ProtocolError(f"SET_TARGETS payload has an odd length {len(payload)}")
    return struct.unpack(f"<{len(payload) // 2}H", payload)


def encode_limits(
    lower: np.ndarray | Sequence[int],
    upper: np.ndarray | Sequence[int],
    step: np.ndarray | Sequence[int],
) -> bytes:
    """SET_LIMITS payload: per actuator (lower u16, upper u16, max_step u16)."""
    body = b""
    for lo, hi, st in zip(lower, upper, step, strict=True):
        body += struct.pack("<HHH", int(lo), int(hi), int(st))
    return body


def decode_limits(payload: bytes) -> tuple[tuple[int, ...], tuple[int, ...], tuple[int, ...]]:
    if len(payload) % 6:
        raise ProtocolError(f"SET_LIMITS payload has a bad length {len(payload)}")
    vals = struct.unpack(f"<{len(payload) // 2}H", payload)
    return tuple(vals[0::3]), tuple(vals[1::3]), tuple(vals[2::3])


def decode_stats(payload: bytes) -> dict[str, int]:
    if len(payload) != 2 * len(STATS_FIELDS):
        raise ProtocolError(
            f"STATS payload has {len(payload)} bytes, expected {2 * len(STATS_FIELDS)}"
        )
    return dict(zip(STATS_FIELDS, struct.unpack(f"<{len(STATS_FIELDS)}H", payload), strict=True))


# ---- host driver --------------------------------------------------------------------------
class S2RProtocol(Protocol):
    """Talks to arm3 firmware (or its emulator): every request is acknowledged, CRC-checked,
    retried with the same SEQ (the device recognises a retransmission and does not re-apply it).

    ``pipeline``: ``write_targets`` sends SET_TARGETS and returns at once; its reply is collected
    before the next request goes out (``settle``), and a lost one is retransmitted then with the
    same SEQ, as a retry is. A control loop then waits for one round trip a period (its
    reading), not two: the command's reply arrives while it sleeps."""

    name = "s2r"
    default_baud = 115200
    description = "sim2real arm3 firmware (framed binary, CRC-16)"
    supports_pipeline = True

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._seq = 0
        self.boot_id: int | None = None
        self._reset_to: int | None = None
        self.last_flags = 0
        self.pipeline = False
        self._pending: tuple[int, bytes] | None = None  # a posted SET_TARGETS: (seq, frame)

    @classmethod
    def unit_frame(cls, spec: ArmSpec) -> UnitFrame:
        s = spec.servo
        return UnitFrame(
            units="us",
            unit_min=round(s.pulse_min_us),
            unit_max=round(s.pulse_max_us),
            center_units=(s.pulse_min_us + s.pulse_max_us) / 2.0,
            units_per_rad=s.us_per_rad,
        )

    @classmethod
    def make_framer(cls) -> Framer:
        # The host is lenient about gaps: a network bridge (socket://, rfc2217://) may pause
        # mid-frame; the CRC and the rescan catch anything the gap rule would have.
        return S2RFramer(gap_s=HOST_GAP_S)

    def settle(self) -> None:
        """Collect the reply to a posted SET_TARGETS (its state checks the boot id; a refusal
        raises here). Waits only if it has not arrived yet."""
        pending, self._pending = self._pending, None
        if pending is not None:
            self._state(self._exchange(pending[0], pending[1], SET_TARGETS, posted=True))

    def _request(self, msg_type: int, payload: bytes = b"") -> S2RFrame:
        if msg_type == TORQUE and payload == b"\x00":
            with contextlib.suppress(HardwareError):  # torque off goes out whatever happened
                self.settle()  # to the posted command
        else:
            self.settle()
        return self._exchange(*self._next_frame(msg_type, payload), msg_type)

    def _next_frame(self, msg_type: int, payload: bytes) -> tuple[int, bytes]:
        """A new request's SEQ and its encoded frame."""
        self._seq = (self._seq + 1) & 0xFF
        return self._seq, encode_frame(self._seq, msg_type, payload)

    def _exchange(
        self, seq: int, frame_bytes: bytes, msg_type: int, posted: bool = False
    ) -> S2RFrame:
        """Send ``frame_bytes`` (unless ``posted``: it went out already, and its reply may be
        queued) and wait for its reply, retransmitting with the same SEQ."""
        want = msg_type | REPLY
        what = MESSAGE_NAMES.get(msg_type, hex(msg_type))
        first = [posted]

        def attempt() -> S2RFrame | None:
            got: list[S2RFrame] = []
            late = 0

            def on_frame(_t: float, f: Any) -> bool:
                nonlocal late
                if f.seq == seq and f.type in (want, ERROR):
                    got.append(f)
                    return True
                late += 1
                return False

            queued, first[0] = first[0], False
            request = None if queued else frame_bytes
            done, stale = self.link.transact(request, on_frame, self.timeout_s, queued=queued)
            self.stats.stale_frames += stale + late
            if not done:
                self.stats.timeouts += 1
                return None
            return got[0]

        reply = self._retry(what, attempt)
        if reply.type == ERROR:
            self.stats.device_errors += 1
            code = reply.payload[0] if reply.payload else 0
            text = ERROR_NAMES.get(code, f"error code {code}")
            if code == ERR_TORQUE_OFF:
                if msg_type != PING:
                    # a reboot also leaves the torque off: tell the two apart by the boot id
                    self._check_boot(PongPayload.decode(self._request(PING).payload).boot_id)
                raise SafetyError(
                    f"s2r device refused {what}: {text}; call enable() (or home) to resume"
                )
            raise ProtocolError(f"s2r device refused {what}: {text}")
        return reply

    def ping(self) -> DeviceInfo:
        pong = PongPayload.decode(self._request(PING).payload)
        if pong.proto_version != PROTO_VERSION:
            raise ProtocolError(
                f"firmware speaks s2r protocol version {pong.proto_version}, this host speaks "
                f"{PROTO_VERSION}: update the firmware or the host"
            )
        if pong.n_actuators != self.n:
            raise ProtocolError(
                f"firmware drives {pong.n_actuators} actuators, the spec has {self.n}: "
                "regenerate limits.h from this spec and reflash"
            )
        if self.boot_id is None:
            self.boot_id = pong.boot_id
        return DeviceInfo(
            protocol=self.name,
            description=(
                f"arm3 firmware {pong.fw_major}.{pong.fw_minor}, protocol {pong.proto_version}, "
                f"{pong.n_actuators} actuators, watchdog {pong.watchdog_ms} ms"
            ),
            n_actuators=pong.n_actuators,
            boot_id=pong.boot_id,
            limits_crc=pong.limits_crc,
        )

    def _state(self, frame: S2RFrame) -> UnitState:
        st = StatePayload.decode(frame.payload, self.n)
        self.last_flags = st.flags
        self._check_boot(st.boot_id)
        return UnitState(
            positions=np.array(st.positions, dtype=np.int64),
            timestamp_s=time.monotonic(),
            targets=np.array(st.targets, dtype=np.int64),
            torque_on=bool(st.flags & FLAG_TORQUE_ON),
            measured=st.measured_array(),
        )

    def _check_boot(self, boot_id: int) -> None:
        if self.boot_id is None:
            self.boot_id = boot_id
        elif boot_id != self.boot_id:
            self._reset_to = boot_id
            raise DeviceResetError(
                f"device reset detected on {self.link.url!r} (boot id {self.boot_id:#06x} -> "
                f"{boot_id:#06x}, a brown-out or USB reset?): its torque is off; call enable() "
                "(or home) to resume"
            )

    def forget_reset(self) -> None:
        if self._reset_to is not None:
            self.boot_id = self._reset_to
            self._reset_to = None

    @property
    def reset_pending(self) -> bool:
        return self._reset_to is not None

    def configure(
        self,
        lower_units: np.ndarray,
        upper_units: np.ndarray,
        step_units: np.ndarray,
        speed_units_per_s: np.ndarray,
    ) -> None:
        """Tighten the firmware's limits to the host's (it refuses to widen its compiled ones)."""
        self._request(SET_LIMITS, encode_limits(lower_units, upper_units, step_units))

    def read_state(self) -> UnitState:
        return self._state(self._request(READ_STATE))

    def write_targets(self, units: np.ndarray) -> UnitState | None:
        if not self.pipeline:
            return self._state(self._request(SET_TARGETS, encode_targets(units)))
        self.settle()
        seq, frame_bytes = self._next_frame(SET_TARGETS, encode_targets(units))
        self.stats.stale_frames += self.link.post(frame_bytes)
        self._pending = (seq, frame_bytes)
        return None

    def set_torque(self, on: bool, hold_units: np.ndarray | None = None) -> None:
        """Torque on: servos with a pot hold where they are (the firmware reads it), the others
        start from ``hold_units`` (where this host last sent them) or their output pulse."""
        self._request(TORQUE, encode_torque(on, hold_units))

    def heartbeat(self) -> None:
        self._request(HEARTBEAT)

    def get_stats(self) -> dict[str, int]:
        return decode_stats(self._request(GET_STATS).payload)
