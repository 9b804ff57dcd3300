"""The three emulated devices: our firmware (s2r), a Feetech STS bus, a Pololu Maestro.

Each takes raw bytes from the wire and returns raw reply bytes, keeps its own registers and
rules, and tells the servo bank what to do. The physical truth -- how a servo's units map to the
joint angle -- is the emulator's *mounting* calibration, which the host does not see: calibration
tests give the emulator an offset mounting and check that the procedure recovers it.
"""

from __future__ import annotations

import struct
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from hardware.emulator.dynamics import ServoBank
from hardware.emulator.firmware import AppliedCommand, FirmwareCore
from hardware.firmware.limits import NO_POT, firmware_limits
from hardware.joint_calibration import ArmCalibration
from hardware.protocols import feetech as ft
from hardware.protocols import maestro as ms
from hardware.protocols.feetech import FeetechFramer, FeetechPacket
from hardware.spec import ArmSpec

LogFn = Callable[[AppliedCommand], None]


class EmulatedDevice(ABC):
    """Device side of one protocol."""

    protocol: ClassVar[str]

    def __init__(
        self,
        spec: ArmSpec,
        mounting: ArmCalibration,
        servos: ServoBank,
        log: LogFn,
        boot_id: int,
        now_s: float,
        options: dict[str, Any],
    ) -> None:
        self.spec = spec
        self.mounting = mounting
        self.servos = servos
        self.log = log
        self.ids = spec.actuator_ids
        self.n = spec.n_actuators
        self.options = options
        self.boot_id = boot_id
        self.start_s = now_s

    @abstractmethod
    def receive(self, data: bytes, now_s: float) -> list[bytes]:
        """Bytes from the host; returns reply byte strings in order."""

    @abstractmethod
    def tick(self, now_s: float) -> None:
        """Device-side control loop (watchdogs, slew)."""

    @abstractmethod
    def drive(self) -> tuple[np.ndarray, np.ndarray]:
        """(target_rad (n,), powered (n,) bool): what the servos are told right now."""

    @abstractmethod
    def reset(self, now_s: float, boot_id: int) -> None:
        """Brown-out: volatile state back to power-on defaults."""

    def next_deadline_s(self) -> float | None:
        """When tick() must run next at the latest (a watchdog), or None."""
        return None

    def reply_delay_s(self, reply: bytes) -> float:
        """How long the device waits before it starts sending ``reply`` (a servo's return
        delay), on top of the emulator's processing latency."""
        return 0.0

    def stats(self) -> dict[str, int]:
        return {}

    def reading_units(self) -> np.ndarray:
        """The servos' measured positions in device units (through the true mounting)."""
        return self.mounting.to_units(self.servos.reading_rad())


# ---- s2r: our firmware --------------------------------------------------------------------------
class S2RDevice(EmulatedDevice):
    """The arm3 firmware model in the build the spec asks for, as the sketch would be generated
    from it: actuators with ``feedback: measured`` have their potentiometer wired to an analog
    input (the hobby mod) and report where the horn is; the others are bare PWM servos and report
    the pulse they were sent (commanded), whatever the horn does."""

    protocol = "s2r"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        flashed = self.options.get("flashed_calibration")
        self.limits = firmware_limits(self.spec, flashed)
        self._pots = [i for i in range(self.n) if self.limits.pot_channel[i] != NO_POT]
        self._boot(self.boot_id, self.start_s)

    def _boot(self, boot_id: int, now_s: float) -> None:
        self.core = FirmwareCore(self.limits, boot_id, now_ms=int(now_s * 1000), on_log=self.log)
        self._sample_pots()

    def _sample_pots(self) -> None:
        """The ADC counts each wired pot reads now (the horn through the true mounting)."""
        if not self._pots:
            return
        us = self.mounting.to_units_float(self.servos.reading_rad())
        for i in self._pots:
            self.core.set_pot(i, self.limits.pot_counts(i, float(us[i])))

    def receive(self, data: bytes, now_s: float) -> list[bytes]:
        now_ms = int(now_s * 1000)
        self.core.tick(now_ms)
        self._sample_pots()
        return self.core.feed(data, now_ms)

    def tick(self, now_s: float) -> None:
        self.core.tick(int(now_s * 1000))

    def drive(self) -> tuple[np.ndarray, np.ndarray]:
        target = self.mounting.from_units(np.array(self.core.output))
        return target, np.full(self.n, self.core.attached)

    def reset(self, now_s: float, boot_id: int) -> None:
        self._boot(boot_id, now_s)

    def next_deadline_s(self) -> float | None:
        ms = self.core.next_deadline_ms()
        return None if ms is None else ms / 1000.0

    def stats(self) -> dict[str, int]:
        return dict(self.core.stats.__dict__)


# ---- Feetech STS bus ----------------------------------------------------------------------------
class _StsServo:
    """One STS3215's control table."""

    def __init__(self, sid: int, lower: int, upper: int, present: int) -> None:
        self.regs = bytearray(256)
        struct.pack_into("<H", self.regs, ft.ADDR_MODEL, ft.STS3215_MODEL)
        self.regs[ft.ADDR_FIRMWARE] = 3
        self.regs[ft.ADDR_ID] = sid
        self.regs[ft.ADDR_BAUD] = 0  # 1 Mbps
        self.regs[ft.ADDR_RETURN_DELAY] = ft.FACTORY_RETURN_DELAY  # 500 us
        self.regs[ft.ADDR_STATUS_RETURN_LEVEL] = ft.FACTORY_STATUS_RETURN_LEVEL
        struct.pack_into("<HH", self.regs, ft.ADDR_MIN_LIMIT, lower, upper)
        self.power_on(present)

    def power_on(self, present: int) -> None:
        r = self.regs
        r[ft.ADDR_TORQUE_ENABLE] = 0
        struct.pack_into("<H", r, ft.ADDR_GOAL_POSITION, present)
        struct.pack_into("<H", r, ft.ADDR_TORQUE_LIMIT, 1000)
        r[ft.ADDR_LOCK] = 1

    @property
    def limits(self) -> tuple[int, int]:
        lo, hi = struct.unpack_from("<HH", self.regs, ft.ADDR_MIN_LIMIT)
        return int(lo), int(hi)

    def write(self, address: int, data: bytes) -> tuple[int, bool]:
        """Write registers; returns (error bits, goal changed)."""
        if address < ft.ADDR_TORQUE_ENABLE and self.regs[ft.ADDR_LOCK] != 0:
            return 0, False  # EEPROM is locked: ignored
        err = 0
        goal_changed = False
        self.regs[address : address + len(data)] = data
        if address <= ft.ADDR_GOAL_POSITION + 1 and address + len(data) > ft.ADDR_GOAL_POSITION:
            goal = ft.from_sign_magnitude(
                struct.unpack_from("<H", self.regs, ft.ADDR_GOAL_POSITION)[0], 15
            )
            lo, hi = self.limits
            if not (lo == 0 and hi == 0):
                clamped = min(max(goal, lo), hi)
                if clamped != goal:
                    err |= ft.ERRBIT_ANGLE
                    struct.pack_into("<H", self.regs, ft.ADDR_GOAL_POSITION, clamped)
            goal_changed = True
        return err, goal_changed

    @property
    def goal(self) -> int:
        return ft.from_sign_magnitude(
            struct.unpack_from("<H", self.regs, ft.ADDR_GOAL_POSITION)[0], 15
        )


class FeetechDevice(EmulatedDevice):
    """A bus of STS3215 servos behind one USB adapter. No watchdog: real STS servos have none.
    Factory settings except the ids (the spec's, as the hardware guide has the user set them):
    1 Mbps, a 500 us return delay before every status packet, status return level 1."""

    protocol = "feetech"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.framer = FeetechFramer()
        lo, hi = self.mounting.unit_limits(self.spec)
        present = self.reading_units()
        self.bus: dict[int, _StsServo] = {
            sid: _StsServo(sid, int(lo[i]), int(hi[i]), int(present[i]))
            for i, sid in enumerate(self.ids)
        }
        self._pending: dict[int, tuple[int, bytes]] = {}

    def _refresh(self) -> None:
        reading = self.reading_units()
        scale = self.mounting.scale_units_per_rad * self.mounting.direction
        speed = np.rint(self.servos.horn_vel_rad_s * scale).astype(int)
        load = np.rint(self.servos.effort * self.mounting.direction * 1000).astype(int)
        for i, sid in enumerate(self.ids):
            r = self.bus[sid].regs
            struct.pack_into("<H", r, ft.ADDR_PRESENT_POSITION, int(reading[i]))
            struct.pack_into(
                "<H", r, ft.ADDR_PRESENT_SPEED, ft.to_sign_magnitude(int(speed[i]), 15)
            )
            struct.pack_into("<H", r, ft.ADDR_PRESENT_LOAD, ft.to_sign_magnitude(int(load[i]), 10))
            r[ft.ADDR_PRESENT_VOLTAGE] = 120
            r[ft.ADDR_PRESENT_TEMPERATURE] = 30

    def _status(self, sid: int, err: int, params: bytes = b"") -> bytes:
        return ft.encode_packet(sid, err, params)

    def _log_goals(self, now_s: float, sids: list[int], requested: list[int]) -> None:
        self.log(
            AppliedCommand(
                now_s,
                "targets",
                tuple(sids),
                tuple(requested),
                tuple(self.bus[s].goal for s in sids),
            )
        )

    def receive(self, data: bytes, now_s: float) -> list[bytes]:
        out: list[bytes] = []
        for p in self.framer.feed(data, now_s):
            out.extend(self._handle(p, now_s))
        return out

    def _handle(self, p: FeetechPacket, now_s: float) -> list[bytes]:
        ins, prm = p.code, p.params
        if ins == ft.INST_SYNC_WRITE and p.id == ft.BROADCAST_ID and len(prm) >= 2:
            addr, size = prm[0], prm[1]
            body = prm[2:]
            if size == 0 or len(body) % (size + 1):
                return []
            sids, req = [], []
            torque = []
            for k in range(0, len(body), size + 1):
                sid, chunk = body[k], body[k + 1 : k + 1 + size]
                if sid not in self.bus:
                    continue
                before = self.bus[sid].goal
                _, goal_changed = self.bus[sid].write(addr, chunk)
                if goal_changed:
                    sids.append(sid)
                    req.append(
                        ft.from_sign_magnitude(
                            struct.unpack_from("<H", chunk, ft.ADDR_GOAL_POSITION - addr)[0], 15
                        )
                        if addr <= ft.ADDR_GOAL_POSITION
                        else before
                    )
                if addr <= ft.ADDR_TORQUE_ENABLE < addr + size:
                    torque.append((sid, chunk[ft.ADDR_TORQUE_ENABLE - addr]))
            if sids:
                self._log_goals(now_s, sids, req)
            if torque:
                self.log(
                    AppliedCommand(
                        now_s,
                        "torque",
                        tuple(s for s, _ in torque),
                        tuple(v for _, v in torque),
                        tuple(v for _, v in torque),
                    )
                )
            return []
        if ins == ft.INST_SYNC_READ and p.id == ft.BROADCAST_ID and len(prm) >= 2:
            addr, size = prm[0], prm[1]
            self._refresh()
            return [
                self._status(sid, 0, bytes(self.bus[sid].regs[addr : addr + size]))
                for sid in prm[2:]
                if sid in self.bus
            ]
        targets = list(self.bus) if p.id == ft.BROADCAST_ID else [p.id] if p.id in self.bus else []
        out = []
        for sid in targets:
            servo = self.bus[sid]
            if ins == ft.INST_PING:
                out.append(self._status(sid, 0))
            elif ins == ft.INST_READ and len(prm) == 2:
                self._refresh()
                out.append(self._status(sid, 0, bytes(servo.regs[prm[0] : prm[0] + prm[1]])))
            elif ins in (ft.INST_WRITE, ft.INST_REG_WRITE) and len(prm) >= 2:
                if ins == ft.INST_REG_WRITE:
                    self._pending[sid] = (prm[0], prm[1:])
                    err = 0
                else:
                    err = self._write_one(sid, prm[0], prm[1:], now_s)
                if p.id != ft.BROADCAST_ID and servo.regs[ft.ADDR_STATUS_RETURN_LEVEL] != 0:
                    out.append(self._status(sid, err))
            elif ins == ft.INST_ACTION and sid in self._pending:
                addr, chunk = self._pending.pop(sid)
                self._write_one(sid, addr, chunk, now_s)
        return out

    def _write_one(self, sid: int, addr: int, chunk: bytes, now_s: float) -> int:
        err, goal_changed = self.bus[sid].write(addr, chunk)
        if goal_changed and addr <= ft.ADDR_GOAL_POSITION:
            req = ft.from_sign_magnitude(
                struct.unpack_from("<H", chunk, ft.ADDR_GOAL_POSITION - addr)[0], 15
            )
            self._log_goals(now_s, [sid], [req])
        if addr <= ft.ADDR_TORQUE_ENABLE < addr + len(chunk):
            v = chunk[ft.ADDR_TORQUE_ENABLE - addr]
            self.log(AppliedCommand(now_s, "torque", (sid,), (v,), (v,)))
        return err

    def tick(self, now_s: float) -> None:
        pass

    def reply_delay_s(self, reply: bytes) -> float:
        servo = self.bus.get(reply[2]) if len(reply) > 2 else None
        return 0.0 if servo is None else 2e-6 * servo.regs[ft.ADDR_RETURN_DELAY]

    def drive(self) -> tuple[np.ndarray, np.ndarray]:
        goals = np.array([self.bus[s].goal for s in self.ids])
        powered = np.array([self.bus[s].regs[ft.ADDR_TORQUE_ENABLE] != 0 for s in self.ids])
        return self.mounting.from_units(goals), powered

    def reset(self, now_s: float, boot_id: int) -> None:
        present = self.reading_units()
        for i, sid in enumerate(self.ids):
            self.bus[sid].power_on(int(present[i]))
        self.framer.reset()
        self._pending.clear()

    def stats(self) -> dict[str, int]:
        return self.framer.stats.as_dict()


# ---- Pololu Maestro -----------------------------------------------------------------------------
class MaestroDevice(EmulatedDevice):
    """A Maestro in compact-protocol mode. Factory settings by default: Serial CRC off (option
    ``crc``) and no serial timeout (option ``serial_timeout_s``, seconds; > 0 switches every
    channel off that long after the last command, like the Maestro's "Timeout" setting). Channel
    ranges are the spec's pulse range, as the hardware guide has the user set them."""

    protocol = "maestro"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.crc = bool(self.options.get("crc", False))
        self.serial_timeout_s = float(self.options.get("serial_timeout_s", 0.0))
        frame = self.mounting.frame
        self.ch_min, self.ch_max = frame.unit_min, frame.unit_max
        self.n_channels = max(6, max(self.ids) + 1)
        self.stat_counts = {"commands": 0, "crc_errors": 0, "protocol_errors": 0}
        self.reset(self.start_s, self.boot_id)

    def reset(self, now_s: float, boot_id: int) -> None:
        self.target = [0] * self.n_channels
        self.position = [0.0] * self.n_channels
        self.speed = [0] * self.n_channels
        self.errors = 0
        self._cmd: int | None = None
        self._data: list[int] = []
        self._last_cmd_s = now_s
        self._last_tick_s = now_s
        self._timed_out = False

    def _need(self) -> int | None:
        if self._cmd == ms.CMD_SET_MULTIPLE_TARGETS:
            return None if not self._data else 2 + 2 * self._data[0]
        return ms.DATA_BYTES[self._cmd] if self._cmd is not None else None

    def receive(self, data: bytes, now_s: float) -> list[bytes]:
        self.tick(now_s)
        out: list[bytes] = []
        for b in data:
            if b & 0x80:
                if self._cmd is not None:
                    self.errors |= ms.ERR_SERIAL_PROTOCOL  # incomplete command: resync here
                    self.stat_counts["protocol_errors"] += 1
                self._cmd, self._data = None, []
                if b in ms.DATA_BYTES or b == ms.CMD_SET_MULTIPLE_TARGETS:
                    self._cmd = b
                elif b != ms.POLOLU_START:
                    self.errors |= ms.ERR_SERIAL_PROTOCOL
                    self.stat_counts["protocol_errors"] += 1
            elif self._cmd is None:
                self.errors |= ms.ERR_SERIAL_PROTOCOL
                self.stat_counts["protocol_errors"] += 1
                continue
            else:
                self._data.append(b)
            need = self._need()
            if self._cmd is None or need is None:
                continue
            if len(self._data) == need + (1 if self.crc else 0):
                cmd, args = self._cmd, self._data[:need]
                crc_byte = self._data[need] if self.crc else 0
                self._cmd, self._data = None, []
                if self.crc and ms.crc7(bytes([cmd, *args])) != crc_byte:
                    self.errors |= ms.ERR_SERIAL_CRC  # the Maestro ignores the command
                    self.stat_counts["crc_errors"] += 1
                    continue
                out.extend(self._run(cmd, args, now_s))
        return out

    def _run(self, cmd: int, args: list[int], now_s: float) -> list[bytes]:
        self.stat_counts["commands"] += 1
        self._last_cmd_s = now_s
        if cmd == ms.CMD_SET_TARGET:
            ch, val = args[0], args[1] | (args[2] << 7)
            self._set_target(ch, val, now_s)
        elif cmd == ms.CMD_SET_MULTIPLE_TARGETS:
            count, first = args[0], args[1]
            for k in range(count):
                self._set_target(first + k, args[2 + 2 * k] | (args[3 + 2 * k] << 7), now_s)
        elif cmd == ms.CMD_SET_SPEED:
            if args[0] < self.n_channels:
                self.speed[args[0]] = args[1] | (args[2] << 7)
        elif cmd == ms.CMD_SET_ACCELERATION:
            pass
        elif cmd == ms.CMD_GET_POSITION:
            ch = args[0]
            pos = round(self.position[ch]) if ch < self.n_channels else 0
            return [struct.pack("<H", pos)]
        elif cmd == ms.CMD_GET_MOVING_STATE:
            moving = any(round(p) != t for p, t in zip(self.position, self.target, strict=True))
            return [bytes((1 if moving else 0,))]
        elif cmd == ms.CMD_GET_ERRORS:
            errors, self.errors = self.errors, 0
            return [struct.pack("<H", errors)]
        elif cmd == ms.CMD_GO_HOME:
            for ch in range(self.n_channels):
                self._set_target(ch, 0, now_s)
        return []

    def _set_target(self, ch: int, value: int, now_s: float) -> None:
        if ch >= self.n_channels:
            return
        applied = 0 if value == 0 else min(max(value, self.ch_min), self.ch_max)
        self.target[ch] = applied
        if applied == 0:
            self.position[ch] = 0.0
        elif self.position[ch] == 0.0 or self.speed[ch] == 0:
            self.position[ch] = float(applied)  # from off, or no speed limit: jump
        self._timed_out = False
        self.log(AppliedCommand(now_s, "targets", (ch,), (value,), (applied,)))

    def tick(self, now_s: float) -> None:
        dt = max(0.0, now_s - self._last_tick_s)
        self._last_tick_s = now_s
        if (
            self.serial_timeout_s > 0
            and not self._timed_out
            and any(t != 0 for t in self.target)
            and now_s - self._last_cmd_s >= self.serial_timeout_s
        ):
            self._timed_out = True
            self.errors |= ms.ERR_SERIAL_TIMEOUT
            for ch in range(self.n_channels):
                self.target[ch] = 0
                self.position[ch] = 0.0
            self.log(AppliedCommand(now_s, "watchdog_detach", tuple(self.ids), (), ()))
            return
        for ch in range(self.n_channels):
            t, p, sp = self.target[ch], self.position[ch], self.speed[ch]
            if t == 0 or p == t:
                continue
            if sp == 0:
                self.position[ch] = float(t)
                continue
            delta = sp * dt / 0.010
            self.position[ch] = (
                float(t) if abs(t - p) <= delta else p + (delta if t > p else -delta)
            )

    def next_deadline_s(self) -> float | None:
        if self.serial_timeout_s <= 0 or self._timed_out or not any(self.target):
            return None
        return self._last_cmd_s + self.serial_timeout_s

    def drive(self) -> tuple[np.ndarray, np.ndarray]:
        pos = np.array([self.position[ch] for ch in self.ids])
        powered = pos != 0
        safe = np.where(powered, pos, self.mounting.to_units_float(self.servos.pos))
        return self.mounting.from_units(safe), powered

    def stats(self) -> dict[str, int]:
        return dict(self.stat_counts)


DEVICES: dict[str, type[EmulatedDevice]] = {
    S2RDevice.protocol: S2RDevice,
    FeetechDevice.protocol: FeetechDevice,
    MaestroDevice.protocol: MaestroDevice,
}
