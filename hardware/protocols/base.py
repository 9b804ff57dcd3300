"""What every servo protocol shares: a serial link with a background reader, a framer that turns
bytes into frames (and survives garbage), and the host-side driver interface SerialArm uses.

The reader thread drains the port continuously and parses frames as they arrive, so the control
loop never blocks on I/O longer than one reply timeout, and garbage never piles up in the OS buffer.
"""

from __future__ import annotations

import contextlib
import errno
import threading
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar

import numpy as np
import serial

from hardware.errors import NoReplyError, PortError
from hardware.joint_calibration import UnitFrame
from hardware.spec import ArmSpec

T = TypeVar("T")

_DIALOUT_FIX = (
    "add your user to the dialout group (sudo usermod -aG dialout $USER), then log out and back in"
)


@dataclass
class FramerStats:
    """Receive-side fault counters: every corrupted frame ends up in one of them."""

    frames: int = 0
    crc_errors: int = 0  # checksum/CRC mismatch
    header_errors: int = 0  # impossible length or broken header
    garbage_bytes: int = 0  # bytes dropped while hunting for a frame start
    gap_resets: int = 0  # partial frames abandoned after an inter-byte gap

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


class Framer(ABC):
    """Incremental parser: bytes in, whole validated frames out, never stuck on garbage."""

    def __init__(self) -> None:
        self.stats = FramerStats()

    @abstractmethod
    def feed(self, data: bytes, now_s: float = 0.0) -> list[Any]:
        """Consume bytes; return the frames completed by them (possibly none)."""

    @abstractmethod
    def reset(self) -> None:
        """Drop any partial frame."""


@dataclass(frozen=True)
class DeviceInfo:
    """What a ping learned about the device."""

    protocol: str
    description: str
    n_actuators: int
    boot_id: int | None = None
    limits_crc: int | None = None


@dataclass(frozen=True)
class UnitState:
    """A state reading in the protocol's integer units (SerialArm converts to rad)."""

    positions: np.ndarray  # (n,) int64 servo units
    timestamp_s: float  # time.monotonic() when the reply arrived
    targets: np.ndarray | None = None  # (n,) the device's current targets, if it reports them
    velocities: np.ndarray | None = None  # (n,) units/s, if reported
    loads: np.ndarray | None = None  # (n,) signed fraction of max torque, if reported
    torque_on: bool | None = None
    # (n,) bool: the position is measured (a sensor on the horn), else it is the command the
    # servo was sent. Every protocol says which: the host judges arrival and stalls from it.
    measured: np.ndarray | None = None


@dataclass
class DriverStats:
    """Host-side transaction counters (the bench compares them with injected faults)."""

    requests: int = 0
    retries: int = 0
    timeouts: int = 0
    stale_frames: int = 0  # replies to an earlier, already timed-out request
    readback_mismatches: int = 0  # a written value read back different (then rewritten)
    device_errors: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


def describe_port_error(url: str, exc: BaseException) -> str:
    """One line that says what is wrong with the port and how to fix it."""
    code = getattr(exc, "errno", None)
    text = str(exc)
    if code == errno.ENOENT or "No such file or directory" in text:
        return (
            f"no such serial port {url!r}; plug the arm in or run `sim2real arm find-port` "
            "to list ports"
        )
    if code in (errno.EACCES, errno.EPERM) or "Permission denied" in text:
        return f"permission denied on {url!r}; {_DIALOUT_FIX}"
    if code in (errno.EAGAIN, errno.EBUSY) or "exclusively lock" in text or "busy" in text:
        return (
            f"serial port {url!r} is busy: another program has it open (close the other "
            "terminal, emulator client or `sim2real arm` process)"
        )
    if code == errno.ENOTTY or "Inappropriate ioctl" in text:
        return f"{url!r} is not a serial port"
    if "Connection refused" in text:
        return f"nothing listens at {url!r} (connection refused)"
    return f"cannot open serial port {url!r}: {text}"


def open_serial(url: str, baud: int, *, exclusive: bool = True) -> serial.SerialBase:
    """Open any pyserial URL (/dev/ttyUSB0, a pty path, socket://, rfc2217://, loop://)."""
    try:
        port = serial.serial_for_url(url, do_not_open=True)
        port.baudrate = baud
        port.timeout = 0.05
        port.write_timeout = 1.0
        if exclusive and not url.partition("://")[1]:
            port.exclusive = True
        port.open()
    except (serial.SerialException, OSError, ValueError) as exc:
        raise PortError(describe_port_error(url, exc)) from None
    return port


class Link:
    """An open port plus a daemon thread that reads and frames everything that arrives."""

    def __init__(self, url: str, baud: int, framer: Framer, *, exclusive: bool = True) -> None:
        self.url, self.baud, self.framer = url, baud, framer
        self._exclusive = exclusive
        self._port: serial.SerialBase | None = None
        self._frames: deque[tuple[float, Any]] = deque()
        self._cond = threading.Condition()
        self._tx_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._running = False
        self._error: BaseException | None = None
        self.bytes_in = 0
        self.bytes_out = 0

    # ---- lifecycle ------------------------------------------------------------------------
    def open(self) -> None:
        self._port = open_serial(self.url, self.baud, exclusive=self._exclusive)
        with contextlib.suppress(serial.SerialException, OSError):
            self._port.reset_input_buffer()
        self._running = True
        self._error = None
        self._thread = threading.Thread(target=self._reader, name=f"link-{self.url}", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._running = False
        port = self._port
        if port is not None and hasattr(port, "cancel_read"):
            with contextlib.suppress(serial.SerialException, OSError):
                port.cancel_read()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if port is not None:
            with contextlib.suppress(serial.SerialException, OSError):
                port.close()
        self._port = None
        with self._cond:
            self._cond.notify_all()

    @property
    def is_open(self) -> bool:
        return self._port is not None and self._running

    def _reader(self) -> None:
        port = self._port
        assert port is not None
        while self._running:
            try:
                waiting = port.in_waiting
                data = port.read(waiting if waiting > 0 else 1)
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                if self._running:
                    self._error = exc
                break
            if not data:
                continue
            now = time.monotonic()
            self.bytes_in += len(data)
            frames = self.framer.feed(bytes(data), now)
            if frames:
                with self._cond:
                    self._frames.extend((now, f) for f in frames)
                    self._cond.notify_all()
        with self._cond:
            self._cond.notify_all()

    def _check(self) -> None:
        if self._error is not None:
            raise PortError(
                f"lost serial port {self.url!r}: {self._error} (unplugged or reset?)"
            ) from None
        if self._port is None:
            raise PortError(f"serial port {self.url!r} is not open")

    # ---- io -------------------------------------------------------------------------------
    def write(self, data: bytes) -> None:
        self._check()
        assert self._port is not None
        try:
            self._port.write(data)
        except (serial.SerialException, OSError) as exc:
            raise PortError(f"write to {self.url!r} failed: {exc}") from None
        self.bytes_out += len(data)

    def drain(self) -> int:
        """Drop frames nobody waited for; returns how many."""
        with self._cond:
            n = len(self._frames)
            self._frames.clear()
        return n

    def post(self, request: bytes) -> int:
        """Write ``request`` without waiting for its reply (a pipelined command: the reply is
        collected by the next ``transact(..., queued=True)``). Returns the stale frames
        dropped first, as ``transact`` does."""
        with self._tx_lock:
            stale = self.drain()
            self.write(request)
            return stale

    def transact(
        self,
        request: bytes | None,
        on_frame: Callable[[float, Any], bool],
        timeout_s: float,
        queued: bool = False,
    ) -> tuple[bool, int]:
        """Write ``request`` and feed arriving frames to ``on_frame`` until it returns True or
        the timeout passes. Returns (done, stale) where stale counts frames queued before the
        request (late replies to an earlier attempt). ``queued``: the frames already queued
        are fed too (the reply to a ``post``), not dropped."""
        with self._tx_lock:
            stale = 0 if queued else self.drain()
            if request:
                self.write(request)
            deadline = time.monotonic() + timeout_s
            while True:
                with self._cond:
                    while not self._frames:
                        self._check()
                        remaining = deadline - time.monotonic()
                        if remaining <= 0:
                            return False, stale
                        self._cond.wait(remaining)
                    batch = list(self._frames)
                    self._frames.clear()
                for t, frame in batch:
                    if on_frame(t, frame):
                        return True, stale


class Protocol(ABC):
    """Host side of one servo protocol; SerialArm talks to the device only through this."""

    name: ClassVar[str]
    default_baud: ClassVar[int]
    description: ClassVar[str]

    def __init__(
        self,
        link: Link,
        ids: Sequence[int],
        *,
        timeout_s: float = 0.05,
        retries: int = 3,
    ) -> None:
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be > 0, got {timeout_s}")
        self.link = link
        self.ids = tuple(int(i) for i in ids)
        self.n = len(self.ids)
        self.timeout_s = timeout_s
        self.retries = retries
        self.stats = DriverStats()

    # ---- class-level facts ----------------------------------------------------------------
    @classmethod
    @abstractmethod
    def unit_frame(cls, spec: ArmSpec) -> UnitFrame:
        """The protocol's servo units for this spec's servos."""

    @classmethod
    @abstractmethod
    def make_framer(cls) -> Framer:
        """A framer for what the *device* sends back to the host."""

    # ---- operations -----------------------------------------------------------------------
    @abstractmethod
    def ping(self) -> DeviceInfo:
        """Check the device is there and speaks this protocol."""

    def configure(  # noqa: B027 - optional: not every device can enforce limits
        self,
        lower_units: np.ndarray,
        upper_units: np.ndarray,
        step_units: np.ndarray,
        speed_units_per_s: np.ndarray,
    ) -> None:
        """Push limits (and a speed limit) to the device where it can enforce them."""

    @abstractmethod
    def read_state(self) -> UnitState:
        """One state reading; raises DeviceResetError when the device rebooted."""

    @abstractmethod
    def write_targets(self, units: np.ndarray) -> UnitState | None:
        """Send targets (already safe, in units); returns a state if the reply carried one."""

    @abstractmethod
    def set_torque(self, on: bool, hold_units: np.ndarray | None = None) -> None:
        """Power the servos holding ``hold_units`` (where the device cannot hold by itself), or
        let them go limp."""

    def heartbeat(self) -> None:
        """Keep device-side watchdogs fed without moving anything."""
        self.read_state()

    def forget_reset(self) -> None:  # noqa: B027 - optional hook
        """Accept a rebooted device as the new normal (called by enable())."""

    # Pipelined commands (``write_targets`` returns once its bytes are out; the reply is
    # collected by ``settle`` before the next request), where a protocol implements them.
    supports_pipeline: ClassVar[bool] = False
    pipeline: bool = False

    def settle(self) -> None:  # noqa: B027 - optional hook
        """Collect the reply to a posted command, if one is outstanding."""

    # Where servos without position feedback are assumed to rest while unpowered (set by
    # SerialArm from the spec's park pose).
    rest_units: np.ndarray | None = None

    # ---- helpers --------------------------------------------------------------------------
    def _retry(self, what: str, attempt: Callable[[], T | None]) -> T:
        """Bounded retries; the NoReplyError says whether bytes arrived at all (a baud hint)."""
        garbage0 = self.link.framer.stats.garbage_bytes + self.link.framer.stats.crc_errors
        bytes0 = self.link.bytes_in
        self.stats.requests += 1
        for i in range(self.retries + 1):
            if i:
                self.stats.retries += 1
            result = attempt()
            if result is not None:
                return result
        received = self.link.bytes_in - bytes0
        bad = self.link.framer.stats.garbage_bytes + self.link.framer.stats.crc_errors - garbage0
        if received and bad:
            hint = (
                f"received {received} bytes that did not parse as {self.name} frames: the baud "
                f"rate probably does not match the device (this port runs at {self.link.baud}; "
                f"{self.name} devices default to {self.default_baud})"
            )
        else:
            hint = (
                "no bytes at all: check power, wiring, the port, the protocol and the baud rate "
                f"({self.link.baud} here; {self.name} devices default to {self.default_baud})"
            )
        raise NoReplyError(
            f"no reply from {self.name} device on {self.link.url!r} to {what} after "
            f"{self.retries + 1} tries of {self.timeout_s * 1000:.0f} ms; {hint}"
        )


@dataclass
class Collector:
    """Collects reply frames for one transaction attempt."""

    want: int = 1
    frames: list[Any] = field(default_factory=list)
    stamps: list[float] = field(default_factory=list)
    rejected: int = 0
