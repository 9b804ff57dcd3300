"""The mock hardware: an emulated device served on a pseudo-terminal.

``Emulator(spec, "s2r").start()`` opens a pty (``os.openpty``), returns the slave's path, and
serves the device from a background thread. Any program opens that path as a serial port -- our
``SerialArm``, ``python -m serial.tools.miniterm``, a test with plain pyserial -- no monkeypatching.

What it emulates besides the device logic:
  * wire time: a reply arrives (request bytes + reply bytes) * 10 / baud after the request,
    plus a configurable processing latency and jitter;
  * the host's baud rate: read from the pty's termios; a host at another baud (where the device
    cares) is heard as garbage, like on a real UART;
  * faults: corrupted bytes, dropped frames and delayed replies (per write chunk, which is one
    frame for a host that writes frame by frame), a cut link (``cut``/``restore``), an unplugged
    port (``unplug``) and a brown-out reset (``brownout``);
  * servo dynamics (emulator/dynamics.py), with an optional command latency (a target acts
    ``command_latency_s`` after the device received it), and a thread-safe
    ``true_positions_rad()`` for rendering virtual cameras.
Every command the device applied is logged (``applied()``), so tests compare it with what the
host believes it sent.
"""

from __future__ import annotations

import contextlib
import fcntl
import heapq
import math
import os
import random
import select
import struct
import termios
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hardware.emulator.coupling import BodyCoupling
from hardware.emulator.devices import DEVICES, EmulatedDevice
from hardware.emulator.dynamics import ServoBank, ServoParams
from hardware.emulator.firmware import AppliedCommand
from hardware.emulator.lifecycle import PtyDevice
from hardware.errors import HardwareError
from hardware.joint_calibration import ArmCalibration, nominal_calibration
from hardware.protocols import get_protocol
from hardware.spec import ArmSpec, load_spec

_BOTHER = 0o010000
_TCGETS2 = 0x802C542A
_SPEEDS: dict[int, int] = {
    getattr(termios, name): int(name[1:])
    for name in dir(termios)
    if name.startswith("B") and name[1:].isdigit()
}


def _rate(name: str, value: float) -> float:
    if not 0.0 <= value <= 1.0:
        raise HardwareError(f"{name} must be a probability in [0, 1], got {value!r}")
    return value


@dataclass(frozen=True)
class FaultConfig:
    """Injected faults. Rates are probabilities per chunk (one frame for frame-by-frame hosts)."""

    corrupt_rate: float = 0.0  # one byte of the chunk replaced by a different value
    corrupt_byte_rate: float = 0.0  # every byte independently replaced with this probability
    drop_rate: float = 0.0  # the whole chunk lost
    delay_rate: float = 0.0  # a reply held back by delay_s (it arrives late, out of order)
    delay_s: float = 0.2
    directions: str = "both"  # "rx" (host->device), "tx" (device->host) or "both"
    seed: int = 0

    def __post_init__(self) -> None:
        _rate("corrupt_rate", self.corrupt_rate)
        _rate("corrupt_byte_rate", self.corrupt_byte_rate)
        _rate("drop_rate", self.drop_rate)
        _rate("delay_rate", self.delay_rate)
        if self.delay_s < 0:
            raise HardwareError(f"delay_s must be >= 0, got {self.delay_s!r}")
        if self.directions not in ("rx", "tx", "both"):
            raise HardwareError(f"directions {self.directions!r} is not one of rx, tx, both")


@dataclass(frozen=True)
class EmulatorConfig:
    baud: int | None = None  # None: the protocol's default
    reply_latency_s: float = 0.0002  # device processing time before it starts replying
    latency_jitter_s: float = 0.0  # uniform extra latency in [0, jitter]
    noise_rad: float = 0.0  # std of the position reading noise
    droop_rad: float = 0.0  # sag of the pitch joints while powered
    command_latency_s: float = 0.0  # dead time from receiving a target to the servo acting on it
    tick_s: float = 0.002  # device control loop and dynamics step
    wire_timing: bool = True  # add (request + reply bytes) * 10 / baud to every reply
    check_baud: bool | None = None  # None: yes, except for the Maestro (it auto-detects)
    seed: int = 0
    faults: FaultConfig = field(default_factory=FaultConfig)
    maestro_crc: bool = False  # factory setting: "Serial CRC" off
    maestro_serial_timeout_s: float = 0.0  # factory setting: no serial timeout (0 = off)
    flashed_calibration: ArmCalibration | None = None  # s2r: calibration limits.h was built with

    def __post_init__(self) -> None:
        for key in (
            "reply_latency_s",
            "latency_jitter_s",
            "noise_rad",
            "droop_rad",
            "command_latency_s",
            "maestro_serial_timeout_s",
        ):
            value = getattr(self, key)
            if not (math.isfinite(value) and value >= 0):
                raise HardwareError(f"{key} must be finite and >= 0, got {value!r}")
        if self.tick_s <= 0:
            raise HardwareError(f"tick_s must be > 0, got {self.tick_s!r}")
        if self.baud is not None and self.baud <= 0:
            raise HardwareError(f"baud must be > 0, got {self.baud!r}")


def pty_baud(fd: int) -> int | None:
    """The baud rate the other end of a pty configured (pyserial sets it with termios)."""
    try:
        speed = termios.tcgetattr(fd)[4]
    except termios.error:
        return None
    if speed != _BOTHER:
        return _SPEEDS.get(speed)
    try:
        buf = fcntl.ioctl(fd, _TCGETS2, bytes(44))
        return int(struct.unpack_from("I", buf, 36)[0])
    except OSError:
        return None


class Emulator(BodyCoupling, PtyDevice):
    """An emulated arm on a pty. Use as a context manager, or ``start()`` / ``stop()``."""

    def __init__(
        self,
        spec: ArmSpec | None = None,
        protocol: str = "s2r",
        config: EmulatorConfig | None = None,
        mounting: ArmCalibration | None = None,
        link: str | os.PathLike[str] | None = None,
    ) -> None:
        self.spec = spec or load_spec()
        proto_cls = get_protocol(protocol)
        if protocol not in DEVICES:
            raise HardwareError(
                f"no emulated device for protocol {protocol!r}; valid: {sorted(DEVICES)}"
            )
        self.protocol = protocol
        self.config = config or EmulatorConfig()
        self.baud = self.config.baud or proto_cls.default_baud
        self.check_baud = (
            self.config.check_baud if self.config.check_baud is not None else protocol != "maestro"
        )
        frame = proto_cls.unit_frame(self.spec)
        self.mounting = mounting or nominal_calibration(
            self.spec, protocol, frame, arm_id="emulator"
        )
        self.mounting.check_spec(self.spec)
        self.mounting.check_protocol(protocol, frame)
        self.link = Path(link) if link is not None else None
        self.servos = ServoBank(
            ServoParams.from_spec(
                self.spec,
                self.config.droop_rad,
                self.config.noise_rad,
                self.config.command_latency_s,
            ),
            self.spec.actuator_park_rad,
            seed=self.config.seed,
        )
        self._rng = random.Random(self.config.faults.seed)
        self._jitter_rng = random.Random(self.config.seed + 1)
        self._lock = threading.RLock()
        self._log: list[AppliedCommand] = []
        self._faults = self.config.faults
        self._fault_counts = {
            "rx_corrupted": 0,
            "rx_dropped": 0,
            "tx_corrupted": 0,
            "tx_dropped": 0,
            "tx_delayed": 0,
            "baud_mismatch_chunks": 0,
            "cut_bytes": 0,
        }
        self._boot_counter = self.config.seed * 7919 + 1
        self._cut = False
        self._running = False
        self._thread: threading.Thread | None = None
        self._master = -1
        self._slave = -1
        self._wake_r = -1
        self._wake_w = -1
        self._t0 = 0.0
        self._last_step_s = 0.0
        self._outbox: list[tuple[float, int, bytes]] = []
        self._tx_free_at = 0.0  # emulator time when the device's TX line is idle again
        self._out_seq = 0
        self._device: EmulatedDevice | None = None
        self.device_path = ""
        self.host_baud: int | None = None
        self._iterations = 0
        self._rx_at_s = 0.0  # when the device last received bytes (command latency bookkeeping)

    # ---- lifecycle ------------------------------------------------------------------------
    def start(self) -> str:
        """Open the pty, start serving; returns the path to open (the link, if one was given)."""
        if self._running:
            return self.port
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self._set_slave_baud(self.baud)
        os.set_blocking(self._master, False)
        self.device_path = os.ttyname(self._slave)
        self._wake_r, self._wake_w = os.pipe()
        self._t0 = time.monotonic()
        self._last_step_s = 0.0
        with self._lock:
            self._device = self._make_device(0.0)
        if self.link is not None:
            with contextlib.suppress(FileNotFoundError):
                if self.link.is_symlink():
                    self.link.unlink()
            if self.link.exists():
                self._close_fds()
                raise HardwareError(f"--link {str(self.link)!r} exists and is not a symlink")
            self.link.symlink_to(self.device_path)
        self._running = True
        self._thread = threading.Thread(
            target=self._serve, name=f"emulator-{self.protocol}", daemon=True
        )
        self._thread.start()
        return self.port

    def _pending_input(self) -> int:
        try:
            buf = fcntl.ioctl(self._master, termios.FIONREAD, b"\0\0\0\0")
        except OSError:
            return 0
        return int(struct.unpack("i", buf)[0])

    def sync(self, timeout_s: float = 2.0) -> bool:
        """Wait until every byte the host has written so far has been processed (writes without
        a reply, like a Feetech SYNC_WRITE, are otherwise still in flight)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and self._running:
            if self._pending_input() == 0:
                # two full passes of the serving loop (it sleeps until woken: wake it each time)
                start = self._iterations
                while self._iterations < start + 2 and time.monotonic() < deadline:
                    if self._wake_w >= 0:
                        with contextlib.suppress(OSError):
                            os.write(self._wake_w, b"x")
                    time.sleep(0.0005)
                if self._pending_input() == 0:
                    return True
            time.sleep(0.0005)
        return False

    def _set_slave_baud(self, baud: int) -> None:
        const = getattr(termios, f"B{baud}", None)
        if const is None:
            return
        attrs = termios.tcgetattr(self._slave)
        attrs[4] = attrs[5] = const
        termios.tcsetattr(self._slave, termios.TCSANOW, attrs)

    def _make_device(self, now_s: float) -> EmulatedDevice:
        options: dict[str, Any] = {
            "crc": self.config.maestro_crc,
            "flashed_calibration": self.config.flashed_calibration,
        }
        options["serial_timeout_s"] = self.config.maestro_serial_timeout_s
        return DEVICES[self.protocol](
            self.spec,
            self.mounting,
            self.servos,
            self._append_log,
            self._next_boot_id(),
            now_s,
            options,
        )

    def _next_boot_id(self) -> int:
        self._boot_counter = (self._boot_counter * 1103515245 + 12345) & 0xFFFF
        return self._boot_counter

    def stop(self) -> None:
        self._running = False
        if self._wake_w >= 0:
            with contextlib.suppress(OSError):
                os.write(self._wake_w, b"x")
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        self._close_fds()
        if self.link is not None and self.link.is_symlink():
            with contextlib.suppress(FileNotFoundError):
                self.link.unlink()

    def _close_fds(self) -> None:
        for name in ("_master", "_slave", "_wake_r", "_wake_w"):
            fd = getattr(self, name)
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
                setattr(self, name, -1)

    def now_s(self) -> float:
        """Emulator time: seconds since start()."""
        return time.monotonic() - self._t0

    # ---- serving --------------------------------------------------------------------------
    def _serve(self) -> None:
        """Sleep until there is something to do: bytes from the host, a reply due, or a device
        deadline (a watchdog). Servo motion is integrated lazily (``_advance``) whenever someone
        reads or writes, so an idle emulator does not wake at all."""
        while self._running:
            now = self.now_s()
            wake_at: float | None = None
            with self._lock:
                if self._outbox:
                    wake_at = self._outbox[0][0]
                deadline = self._device.next_deadline_s() if self._device else None
            if deadline is not None:  # the first grid point at or after it
                tick = self.config.tick_s
                due = math.ceil(deadline / tick - 1e-9) * tick + 1e-4
                wake_at = due if wake_at is None else min(wake_at, due)
            timeout = None if wake_at is None else max(0.0, wake_at - now)
            try:
                ready, _, _ = select.select([self._master, self._wake_r], [], [], timeout)
            except (OSError, ValueError):
                break
            now = self.now_s()
            if self._wake_r in ready:
                with contextlib.suppress(OSError):
                    os.read(self._wake_r, 64)
            if self._master in ready:
                try:
                    data = os.read(self._master, 4096)
                except BlockingIOError:
                    data = b""
                except OSError:
                    break
                if data:
                    self._on_rx(data, now)
            with self._lock:
                self._advance(now, exact=False)
            self._flush(now)
            self._iterations += 1

    def _advance(self, now: float, exact: bool = True) -> None:
        """Device ticks, then servo dynamics, up to ``now`` (caller holds the lock).

        The device loop and the dynamics step on a fixed grid (multiples of ``tick_s``), however
        rarely this is called. Bytes from the host split a step where they arrive (``exact``);
        a reader does not (``exact=False`` stops at the last grid point), so the motion does not
        depend on when anyone looked. Once nothing changes any more (the device's drive
        unchanged over a step, every servo at rest, no delayed target queued) it jumps ahead,
        stopping at the device's next deadline."""
        assert self._device is not None
        tick = self.config.tick_s
        t = self._last_step_s
        if not exact:
            now = max(t, math.floor(now / tick + 1e-9) * tick)
        if now <= t:
            return
        # receive() advances to its arrival time before it changes a target, so a new target has
        # been commanded since _last_step_s: its command latency counts from there
        first_target, first_powered = self._device.drive()
        prev = (np.asarray(first_target).copy(), np.asarray(first_powered).copy())
        latency_until = self._rx_at_s + self.config.command_latency_s
        while t < now:
            t_next = min(now, (math.floor(t / tick + 1e-9) + 1) * tick)
            self._device.tick(t_next)
            target, powered = self._device.drive()
            self.servos.advance(t, t_next, target, powered)
            t = t_next
            settled = (
                t < now
                and t >= latency_until
                and np.array_equal(prev[0], target)
                and np.array_equal(prev[1], powered)
                and not np.any(self.servos.vel)
            )
            prev = (np.asarray(target).copy(), np.asarray(powered).copy())
            if settled:
                deadline = self._device.next_deadline_s()
                jump = now if deadline is None or deadline <= t else min(now, deadline)
                jump = max(t, math.floor(jump / tick) * tick) if jump < now else now
                if jump > t:
                    self.servos.advance(t, jump, target, powered)
                    t = jump
        self._last_step_s = now

    def _on_rx(self, data: bytes, now: float) -> None:
        if self._cut:
            self._fault_counts["cut_bytes"] += len(data)
            return
        self.host_baud = pty_baud(self._slave)
        if self.check_baud and self.host_baud is not None and self.host_baud != self.baud:
            # a UART at the wrong baud hears framing noise, not the bytes that were sent
            self._fault_counts["baud_mismatch_chunks"] += 1
            data = bytes(self._rng.randrange(256) for _ in data)
        f = self._faults
        if f.directions in ("rx", "both"):
            if f.drop_rate and self._rng.random() < f.drop_rate:
                self._fault_counts["rx_dropped"] += 1
                return
            corrupted = self._maybe_corrupt(data)
            if corrupted is not None:
                self._fault_counts["rx_corrupted"] += 1
                data = corrupted
        with self._lock:
            self._advance(now)
            assert self._device is not None
            replies = self._device.receive(data, now)
            self._rx_at_s = now
        ready = now + self.config.reply_latency_s
        if self.config.latency_jitter_s:
            ready += self._jitter_rng.uniform(0.0, self.config.latency_jitter_s)
        if self.config.wire_timing:
            ready += len(data) * 10.0 / self.baud  # the request's own bytes on the wire
        for reply in replies:
            with self._lock:
                delay = self._device.reply_delay_s(reply)
            self._queue_reply(reply, ready, delay)

    def _maybe_corrupt(self, data: bytes) -> bytes | None:
        """The chunk with corrupted bytes, or None when this chunk is left alone."""
        f = self._faults
        b = bytearray(data)
        hit = False
        if f.corrupt_rate and self._rng.random() < f.corrupt_rate:
            b[self._rng.randrange(len(b))] ^= self._rng.randrange(1, 256)
            hit = True
        if f.corrupt_byte_rate:
            for i in range(len(b)):
                if self._rng.random() < f.corrupt_byte_rate:
                    b[i] ^= self._rng.randrange(1, 256)
                    hit = True
        return bytes(b) if hit else None

    def _queue_reply(self, reply: bytes, ready: float, delay_s: float = 0.0) -> None:
        """Send ``reply`` once the device is ready and the line is free: a UART sends one byte
        after another, so back-to-back replies (a bus answering a SYNC_READ) queue up."""
        f = self._faults
        if f.directions in ("tx", "both"):
            if f.drop_rate and self._rng.random() < f.drop_rate:
                self._fault_counts["tx_dropped"] += 1
                return
            corrupted = self._maybe_corrupt(reply)
            if corrupted is not None:
                self._fault_counts["tx_corrupted"] += 1
                reply = corrupted
        at = max(ready, self._tx_free_at) + delay_s  # a servo's return delay, then its bytes
        if self.config.wire_timing:
            at += len(reply) * 10.0 / self.baud
        self._tx_free_at = at
        if f.directions in ("tx", "both") and f.delay_rate and self._rng.random() < f.delay_rate:
            self._fault_counts["tx_delayed"] += 1
            at += f.delay_s
        with self._lock:
            self._out_seq += 1
            heapq.heappush(self._outbox, (at, self._out_seq, reply))

    def _flush(self, now: float) -> None:
        while True:
            with self._lock:
                if not self._outbox or self._outbox[0][0] > now:
                    return
                _, _, data = heapq.heappop(self._outbox)
            if self._cut:
                self._fault_counts["cut_bytes"] += len(data)
                continue
            try:
                os.write(self._master, data)
            except BlockingIOError:
                pass  # nobody reads the port: the bytes are lost, as on a real wire
            except OSError:
                return

    # ---- faults ---------------------------------------------------------------------------
    def set_faults(self, faults: FaultConfig) -> None:
        with self._lock:
            self._faults = faults
            self._rng = random.Random(faults.seed)

    def cut(self) -> float:
        """Cut the link (both directions silent). Returns the emulator time of the cut."""
        self._cut = True
        return self.now_s()

    def restore(self) -> None:
        self._cut = False

    def inject_tx(self, data: bytes) -> None:
        """Send raw bytes to the host now (line noise, a device's boot banner)."""
        with self._lock:
            self._out_seq += 1
            heapq.heappush(self._outbox, (self.now_s(), self._out_seq, bytes(data)))
        if self._wake_w >= 0:
            with contextlib.suppress(OSError):
                os.write(self._wake_w, b"x")

    def brownout(self) -> None:
        """Supply dip: the device reboots with a new boot id, torque off, RAM defaults."""
        with self._lock:
            now = self.now_s()
            self._advance(now)
            assert self._device is not None
            self._device.reset(now, self._next_boot_id())
            self.servos.drop_pending()
            self._outbox.clear()
            self._append_log(AppliedCommand(now, "reset", self.spec.actuator_ids, (), ()))

    def unplug(self) -> None:
        """The USB cable is pulled: the port goes away under the host."""
        self._running = False
        if self._wake_w >= 0:
            with contextlib.suppress(OSError):
                os.write(self._wake_w, b"x")
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        self._close_fds()

    # ---- observation (thread-safe) --------------------------------------------------------
    def _append_log(self, entry: AppliedCommand) -> None:
        self._log.append(entry)

    def applied(self, kind: str | None = None) -> list[AppliedCommand]:
        """Everything the device applied so far (optionally only one kind)."""
        with self._lock:
            return [e for e in self._log if kind is None or e.kind == kind]

    def clear_log(self) -> None:
        with self._lock:
            self._log.clear()

    def _catch_up(self) -> None:
        """Integrate up to now before anyone looks (lock held; no-op before start)."""
        if self._device is not None and self._running:
            self._advance(self.now_s(), exact=False)

    def torque_enabled(self) -> np.ndarray:
        """Which servos are powered right now (n_actuators,) bool."""
        with self._lock:
            if self._device is None:
                return np.zeros(self.spec.n_actuators, dtype=bool)
            self._catch_up()
            return np.asarray(self._device.drive()[1], dtype=bool).copy()

    def device_targets_rad(self) -> np.ndarray:
        """What the device drives the servos towards right now, in rad (true mounting)."""
        with self._lock:
            assert self._device is not None
            self._catch_up()
            return np.asarray(self._device.drive()[0], dtype=float).copy()

    def stats(self) -> dict[str, int]:
        with self._lock:
            out = dict(self._fault_counts)
            if self._device is not None:
                out.update({f"device_{k}": v for k, v in self._device.stats().items()})
            return out

    def wait_until(
        self, predicate: Callable[[], bool], timeout_s: float = 2.0, poll_s: float = 0.002
    ) -> bool:
        """Poll ``predicate`` until true or timeout (tests use it instead of fixed sleeps)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if predicate():
                return True
            time.sleep(poll_s)
        return predicate()
