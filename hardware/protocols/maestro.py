"""Protocol 3, ``maestro``: Pololu Maestro USB/serial PWM servo controllers, compact protocol.

Commands (byte-level spec in docs/protocols.md)::

    set target    0x84, channel, target & 0x7F, (target >> 7) & 0x7F    target in quarter-µs
    set speed     0x87, channel, speed & 0x7F, (speed >> 7) & 0x7F      0.25 µs per 10 ms
    get position  0x90, channel              -> 2 bytes, little-endian, quarter-µs
    get errors    0xA1                       -> 2 bytes, little-endian error bits (then cleared)

Command bytes have bit 7 set and data bytes never do, so a receiver resynchronises on the next
command byte. With "Serial CRC" enabled on the Maestro, each command is followed by a CRC-7 byte
(polynomial 0x91, computed LSB first); a command with a bad CRC is ignored and flagged in the
error register. The Maestro ships with Serial CRC *off*, so the driver sends no CRC unless told to
(``crc=True``, CLI ``--maestro-crc``) after the user enabled it in the Maestro Control Center. Replies carry no CRC: the driver checks them for plausibility instead. A target of
0 stops the pulses (the servo goes limp), which is how torque is switched off.
"""

from __future__ import annotations

import struct
import time
from typing import Any

import numpy as np

from hardware.errors import DeviceResetError, ProtocolError, SafetyError
from hardware.joint_calibration import UnitFrame
from hardware.protocols.base import DeviceInfo, Framer, Protocol, UnitState
from hardware.spec import ArmSpec

CMD_SET_TARGET = 0x84
CMD_SET_SPEED = 0x87
CMD_SET_ACCELERATION = 0x89
CMD_GET_POSITION = 0x90
CMD_GET_MOVING_STATE = 0x93
CMD_SET_MULTIPLE_TARGETS = 0x9F
CMD_GET_ERRORS = 0xA1
CMD_GO_HOME = 0xA2
POLOLU_START = 0xAA

# Error register bits
ERR_SERIAL_SIGNAL = 1 << 0
ERR_SERIAL_OVERRUN = 1 << 1
ERR_SERIAL_BUFFER_FULL = 1 << 2
ERR_SERIAL_CRC = 1 << 3
ERR_SERIAL_PROTOCOL = 1 << 4
ERR_SERIAL_TIMEOUT = 1 << 5
ERROR_BIT_NAMES = {
    ERR_SERIAL_SIGNAL: "serial signal",
    ERR_SERIAL_OVERRUN: "serial overrun",
    ERR_SERIAL_BUFFER_FULL: "serial buffer full",
    ERR_SERIAL_CRC: "serial CRC",
    ERR_SERIAL_PROTOCOL: "serial protocol",
    ERR_SERIAL_TIMEOUT: "serial timeout",
}

# Number of data bytes after each command byte (0x9F is variable: handled separately).
DATA_BYTES: dict[int, int] = {
    CMD_SET_TARGET: 3,
    CMD_SET_SPEED: 3,
    CMD_SET_ACCELERATION: 3,
    CMD_GET_POSITION: 1,
    CMD_GET_MOVING_STATE: 0,
    CMD_GET_ERRORS: 0,
    CMD_GO_HOME: 0,
}
REPLY_BYTES: dict[int, int] = {CMD_GET_POSITION: 2, CMD_GET_MOVING_STATE: 1, CMD_GET_ERRORS: 2}


def crc7(data: bytes | bytearray) -> int:
    """Pololu CRC-7: polynomial 0x91, processed least-significant bit first."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            if crc & 1:
                crc ^= 0x91
            crc >>= 1
    return crc


def with_crc(command: bytes, crc: bool) -> bytes:
    return command + bytes((crc7(command),)) if crc else command


def set_target_cmd(channel: int, target_qus: int) -> bytes:
    if not 0 <= target_qus < 1 << 14:
        raise ValueError(f"target {target_qus} quarter-µs is outside 0..16383")
    return bytes((CMD_SET_TARGET, channel, target_qus & 0x7F, (target_qus >> 7) & 0x7F))


def set_speed_cmd(channel: int, speed: int) -> bytes:
    speed = max(0, min(int(speed), (1 << 14) - 1))
    return bytes((CMD_SET_SPEED, channel, speed & 0x7F, (speed >> 7) & 0x7F))


def get_position_cmd(channel: int) -> bytes:
    return bytes((CMD_GET_POSITION, channel))


def targets_packet(channels: tuple[int, ...], units: np.ndarray, crc: bool) -> bytes:
    """One SET_TARGET per channel (the Micro Maestro has no SET_MULTIPLE_TARGETS)."""
    return b"".join(
        with_crc(set_target_cmd(ch, int(u)), crc) for ch, u in zip(channels, units, strict=True)
    )


class MaestroFramer(Framer):
    """Maestro replies have no framing: pass the bytes through; the driver counts them."""

    def reset(self) -> None:
        pass

    def feed(self, data: bytes, now_s: float = 0.0) -> list[Any]:
        self.stats.frames += 1
        return [data]


class MaestroProtocol(Protocol):
    """Pololu Maestro: set targets without reply, read positions and errors in one burst."""

    name = "maestro"
    default_baud = 115200
    description = "Pololu Maestro PWM servo controller (compact protocol, optional CRC-7)"

    def __init__(self, *args: Any, crc: bool = False, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.crc = crc
        self._torque_expected = False
        self._last_targets: np.ndarray | None = None
        self._unit_max = (1 << 14) - 1

    @classmethod
    def unit_frame(cls, spec: ArmSpec) -> UnitFrame:
        s = spec.servo
        return UnitFrame(
            units="qus",
            unit_min=round(4 * s.pulse_min_us),
            unit_max=round(4 * s.pulse_max_us),
            center_units=2.0 * (s.pulse_min_us + s.pulse_max_us),
            units_per_rad=4.0 * s.us_per_rad,
        )

    @classmethod
    def make_framer(cls) -> Framer:
        return MaestroFramer()

    def _query(self, what: str, request: bytes, n_bytes: int) -> bytes:
        def attempt() -> bytes | None:
            buf = bytearray()

            def on_frame(_t: float, chunk: Any) -> bool:
                buf.extend(chunk)
                return len(buf) >= n_bytes

            done, stale = self.link.transact(request, on_frame, self.timeout_s)
            self.stats.stale_frames += stale
            if not done or len(buf) != n_bytes:
                if done:
                    self.stats.stale_frames += 1  # extra bytes: a late reply got mixed in
                else:
                    self.stats.timeouts += 1
                return None
            return bytes(buf)

        return self._retry(what, attempt)

    def _send(self, commands: list[bytes]) -> None:
        self.link.write(b"".join(with_crc(c, self.crc) for c in commands))

    def ping(self) -> DeviceInfo:
        errors = self._read_errors()
        return DeviceInfo(
            protocol=self.name,
            description=(
                f"Pololu Maestro, channels {list(self.ids)}, CRC-7 {'on' if self.crc else 'off'}, "
                f"error register {errors:#06x}"
            ),
            n_actuators=self.n,
        )

    def _read_errors(self) -> int:
        raw = self._query("GET_ERRORS", with_crc(bytes((CMD_GET_ERRORS,)), self.crc), 2)
        return int(struct.unpack("<H", raw)[0])

    def configure(
        self,
        lower_units: np.ndarray,
        upper_units: np.ndarray,
        step_units: np.ndarray,
        speed_units_per_s: np.ndarray,
    ) -> None:
        """The Maestro's own speed limit is its slew-rate limit (units: 0.25 µs per 10 ms)."""
        self._send(
            [
                set_speed_cmd(ch, max(1, int(sp * 0.01)))
                for ch, sp in zip(self.ids, speed_units_per_s, strict=True)
            ]
        )

    def read_state(self) -> UnitState:
        request = b"".join(with_crc(get_position_cmd(ch), self.crc) for ch in self.ids)
        request += with_crc(bytes((CMD_GET_ERRORS,)), self.crc)
        raw = self._query("GET_POSITION", request, 2 * self.n + 2)
        t = time.monotonic()
        vals = struct.unpack(f"<{self.n + 1}H", raw)
        positions, errors = np.array(vals[: self.n], dtype=np.int64), int(vals[self.n])
        if np.any(positions > self._unit_max):
            raise ProtocolError(f"maestro sent impossible positions {positions.tolist()}")
        if errors & ERR_SERIAL_TIMEOUT:
            self._torque_expected = False
            raise SafetyError(
                "maestro serial timeout fired (no command within its timeout): servos are off; "
                "call enable() to resume"
            )
        off = positions == 0
        if self._torque_expected and np.any(off):
            self._torque_expected = False
            raise DeviceResetError(
                f"maestro channel(s) {[c for c, o in zip(self.ids, off, strict=True) if o]} "
                "stopped pulsing although enabled: it rebooted (brown-out?); call enable() to resume"
            )
        if errors & (ERR_SERIAL_CRC | ERR_SERIAL_PROTOCOL) and self._torque_expected:
            # a command was corrupted on the wire and ignored by the Maestro: resend the targets
            self.stats.readback_mismatches += 1
            if self._last_targets is not None:
                self._send_targets(self._last_targets)
        if np.any(off) and self.rest_units is not None:
            positions = np.where(off, self.rest_units, positions)
        return UnitState(
            positions=positions,
            timestamp_s=t,
            torque_on=bool(not np.any(off)),
            measured=np.zeros(self.n, dtype=bool),  # its own output pulse: nothing is felt
        )

    def _send_targets(self, units: np.ndarray) -> None:
        self.link.write(targets_packet(self.ids, units, self.crc))

    def write_targets(self, units: np.ndarray) -> UnitState | None:
        self._last_targets = np.asarray(units, dtype=np.int64).copy()
        self._send_targets(self._last_targets)
        return None

    def set_torque(self, on: bool, hold_units: np.ndarray | None = None) -> None:
        if on:
            if hold_units is None:
                raise ProtocolError("maestro cannot hold by itself: enabling needs hold targets")
            self._read_errors()  # clear stale error bits (a timeout from before, say)
            self.write_targets(hold_units)
        else:
            self._send([set_target_cmd(ch, 0) for ch in self.ids])
        self._torque_expected = on
