"""A line-by-line Python model of the arm3 firmware core (firmware/arm3/src/arm3_core.cpp).

Same framer, same limits, same per-frame step clamp, same integer slew-rate limiter, same
watchdog (hold, then detach), same duplicate detection, same potentiometer map (ADC counts to µs,
for the actuators the build wires a pot to) and the same attach without a snap. tests/hardware/test_firmware.py feeds
identical byte streams and clock ticks to this model and to the compiled C++ core and requires
identical replies, outputs and counters. Times are integer milliseconds, as on the Arduino.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from hardware.firmware.limits import NO_POT, FirmwareLimits
from hardware.protocols import s2r
from hardware.protocols.s2r import S2RFrame, S2RFramer


@dataclass(frozen=True)
class AppliedCommand:
    """One thing a device did to its servos, as logged by the emulator."""

    t_s: float
    kind: str  # "targets", "torque", "limits", "watchdog_hold", "watchdog_detach", "reset"
    ids: tuple[int, ...]
    requested: tuple[int, ...]  # what arrived on the wire (device units)
    applied: tuple[int, ...]  # what the device then used, after its own clamps
    seq: int | None = None


@dataclass
class FirmwareStats:
    rx_frames: int = 0
    crc_errors: int = 0
    header_errors: int = 0
    garbage_bytes: int = 0
    gap_resets: int = 0
    watchdog_trips: int = 0
    clamps: int = 0
    duplicates: int = 0


def _clamp(v: int, lo: int, hi: int) -> int:
    return lo if v < lo else hi if v > hi else v


class FirmwareCore:
    """The device side of protocol s2r. Actuators the build wires a potentiometer to
    (``limits.pot_channel``) report it, mapped to µs, from the counts last given to ``set_pot``
    (the sketch samples the ADC; the emulator computes the counts from the horn); the others
    report their output pulse, as a board driving bare PWM servos can only do."""

    def __init__(
        self,
        limits: FirmwareLimits,
        boot_id: int,
        now_ms: int = 0,
        on_log: Callable[[AppliedCommand], None] | None = None,
    ) -> None:
        self.limits = limits
        self.n = limits.n
        self.boot_id = boot_id & 0xFFFF
        self.pot = [0] * self.n  # ADC counts; survive begin() as the sketch's samples do
        self._on_log = on_log
        self.framer = S2RFramer(gap_s=s2r.GAP_MS / 1000.0)
        self.stats = FirmwareStats()
        self.lower = list(limits.lower_us)
        self.upper = list(limits.upper_us)
        self.step = list(limits.max_step_us)
        self.target = list(limits.park_us)
        self.output = list(limits.park_us)
        self.carry = [0] * self.n
        self.attached = False
        self.holding = False
        self.clamped = False
        self.custom_limits = False
        self.last_valid_ms = now_ms
        self.hold_since_ms = now_ms
        self.last_tick_ms = now_ms
        self._have_last = False
        self._last_seq = 0
        self._last_crc = 0

    # ---- receive --------------------------------------------------------------------------
    def feed(self, data: bytes, now_ms: int) -> list[bytes]:
        """Bytes from the wire; returns the reply frames in order."""
        frames = self.framer.feed(data, now_ms / 1000.0)
        fs = self.framer.stats
        self.stats.crc_errors = fs.crc_errors
        self.stats.header_errors = fs.header_errors
        self.stats.garbage_bytes = fs.garbage_bytes
        self.stats.gap_resets = fs.gap_resets
        return [self._handle(f, now_ms) for f in frames]

    def _log(
        self,
        now_ms: int,
        kind: str,
        requested: tuple[int, ...],
        applied: tuple[int, ...],
        seq: int | None,
    ) -> None:
        if self._on_log is not None:
            self._on_log(
                AppliedCommand(
                    now_ms / 1000.0, kind, self.limits.servo_ids, requested, applied, seq
                )
            )

    def _error(self, seq: int, code: int, msg_type: int) -> bytes:
        return s2r.encode_frame(seq, s2r.ERROR, bytes((code, msg_type)))

    def _handle(self, f: S2RFrame, now_ms: int) -> bytes:
        self.stats.rx_frames += 1
        self.last_valid_ms = now_ms
        self.holding = False
        dup = self._have_last and f.seq == self._last_seq and f.crc == self._last_crc
        self._have_last, self._last_seq, self._last_crc = True, f.seq, f.crc
        if dup:
            self.stats.duplicates += 1
        n, p, t = self.n, f.payload, f.type
        reply_type = t | s2r.REPLY
        if t == s2r.PING:
            if p:
                return self._error(f.seq, s2r.ERR_BAD_LENGTH, t)
            pong = s2r.PongPayload(
                s2r.PROTO_VERSION,
                s2r.FW_VERSION[0],
                s2r.FW_VERSION[1],
                n,
                self.boot_id,
                self.limits.crc,
                self.limits.watchdog_ms,
            )
            return s2r.encode_frame(f.seq, reply_type, pong.encode())
        if t == s2r.SET_TARGETS:
            if len(p) != 2 * n:
                return self._error(f.seq, s2r.ERR_BAD_LENGTH, t)
            if not self.attached:
                return self._error(f.seq, s2r.ERR_TORQUE_OFF, t)
            if not dup:
                self._apply_targets(s2r.decode_targets(p), now_ms, f.seq)
            return s2r.encode_frame(f.seq, reply_type, self._state_payload())
        if t == s2r.READ_STATE:
            if p:
                return self._error(f.seq, s2r.ERR_BAD_LENGTH, t)
            return s2r.encode_frame(f.seq, reply_type, self._state_payload())
        if t == s2r.SET_LIMITS:
            if len(p) != 6 * n:
                return self._error(f.seq, s2r.ERR_BAD_LENGTH, t)
            lo, hi, st = s2r.decode_limits(p)
            for i in range(n):
                ok = (
                    self.limits.lower_us[i] <= lo[i] < hi[i] <= self.limits.upper_us[i]
                    and 1 <= st[i] <= self.limits.max_step_us[i]
                )
                if not ok:
                    return self._error(f.seq, s2r.ERR_LIMIT_RANGE, t)
            if not dup:
                self.lower, self.upper, self.step = list(lo), list(hi), list(st)
                for i in range(n):
                    self.target[i] = _clamp(self.target[i], self.lower[i], self.upper[i])
                self.custom_limits = True
                self._log(now_ms, "limits", tuple(lo) + tuple(hi), tuple(st), f.seq)
            return s2r.encode_frame(f.seq, reply_type)
        if t == s2r.TORQUE:
            if len(p) not in (1, 1 + 2 * n):
                return self._error(f.seq, s2r.ERR_BAD_LENGTH, t)
            if p[0] > 1 or (len(p) > 1 and p[0] != 1):
                return self._error(f.seq, s2r.ERR_BAD_VALUE, t)
            if not dup:
                if p[0] == 1:
                    self._attach(s2r.decode_targets(p[1:]) if len(p) > 1 else None)
                else:
                    self.attached = False
                self._log(now_ms, "torque", (p[0],), (1 if self.attached else 0,), f.seq)
            return s2r.encode_frame(f.seq, reply_type)
        if t == s2r.HEARTBEAT:
            if p:
                return self._error(f.seq, s2r.ERR_BAD_LENGTH, t)
            return s2r.encode_frame(f.seq, reply_type)
        if t == s2r.GET_STATS:
            if p:
                return self._error(f.seq, s2r.ERR_BAD_LENGTH, t)
            vals = [getattr(self.stats, k) & 0xFFFF for k in s2r.STATS_FIELDS]
            return s2r.encode_frame(
                f.seq, reply_type, b"".join(v.to_bytes(2, "little") for v in vals)
            )
        return self._error(f.seq, s2r.ERR_UNKNOWN_TYPE, t)

    def _apply_targets(self, req: tuple[int, ...], now_ms: int, seq: int) -> None:
        clamped = False
        for i in range(self.n):
            v = _clamp(req[i], self.lower[i], self.upper[i])
            v = _clamp(v, self.target[i] - self.step[i], self.target[i] + self.step[i])
            v = _clamp(v, self.lower[i], self.upper[i])
            if v != req[i]:
                clamped = True
            self.target[i] = v
        self.clamped = clamped
        if clamped:
            self.stats.clamps += 1
        self._log(now_ms, "targets", tuple(req), tuple(self.target), seq)

    def _attach(self, start_us: tuple[int, ...] | None) -> None:
        """Torque on without a snap: a pot servo starts where it is, one without from the host's
        start pulse (only when it was off) or its output; clamped to the limits."""
        for i in range(self.n):
            v = self.output[i]
            if self.measured(i):
                v = self.limits.pot_us(i, self.pot[i])
            elif start_us is not None and not self.attached:
                v = start_us[i]
            self.output[i] = _clamp(v, self.lower[i], self.upper[i])
            self.target[i] = self.output[i]
            self.carry[i] = 0
        self.attached = True

    def set_pot(self, i: int, counts: int) -> None:
        self.pot[i] = int(counts)

    def measured(self, i: int) -> bool:
        return self.limits.pot_channel[i] != NO_POT

    def measured_mask(self) -> int:
        return self.limits.measured_mask

    def position(self, i: int) -> int:
        """Actuator i's reading in µs: its pot, or its output pulse."""
        return self.limits.pot_us(i, self.pot[i]) if self.measured(i) else self.output[i]

    def flags(self) -> int:
        return (
            (s2r.FLAG_TORQUE_ON if self.attached else 0)
            | (s2r.FLAG_WATCHDOG_HOLD if self.holding else 0)
            | (s2r.FLAG_CLAMPED if self.clamped else 0)
            | (s2r.FLAG_CUSTOM_LIMITS if self.custom_limits else 0)
        )

    def _state_payload(self) -> bytes:
        positions = tuple(self.position(i) for i in range(self.n))
        return s2r.StatePayload(
            self.flags(), self.boot_id, positions, tuple(self.target), self.measured_mask()
        ).encode()

    # ---- time -----------------------------------------------------------------------------
    def tick(self, now_ms: int) -> None:
        """Run the control loop once: watchdog, then the slew-rate limiter."""
        dt = (now_ms - self.last_tick_ms) & 0xFFFFFFFF
        dt = min(dt, 1000)
        self.last_tick_ms = now_ms
        if not self.attached:
            return
        if not self.holding:
            if ((now_ms - self.last_valid_ms) & 0xFFFFFFFF) >= self.limits.watchdog_ms:
                self.holding = True
                self.hold_since_ms = now_ms
                self.stats.watchdog_trips += 1
                self.target = list(self.output)
                self.carry = [0] * self.n
                self._log(now_ms, "watchdog_hold", (), tuple(self.output), None)
        elif ((now_ms - self.hold_since_ms) & 0xFFFFFFFF) >= self.limits.hold_ms:
            self.attached = False
            self.holding = False
            self._log(now_ms, "watchdog_detach", (), tuple(self.output), None)
            return
        for i in range(self.n):
            d = self.target[i] - self.output[i]
            if d == 0:
                self.carry[i] = 0
                continue
            budget = self.limits.slew_us_per_s[i] * dt + self.carry[i]
            step, self.carry[i] = divmod(budget, 1000)
            if abs(d) <= step:
                self.output[i] = self.target[i]
                self.carry[i] = 0
            else:
                self.output[i] += step if d > 0 else -step

    def next_deadline_ms(self) -> int | None:
        """When the watchdog needs the next tick (the emulator sleeps until then)."""
        if not self.attached:
            return None
        if self.holding:
            return self.hold_since_ms + self.limits.hold_ms
        return self.last_valid_ms + self.limits.watchdog_ms
