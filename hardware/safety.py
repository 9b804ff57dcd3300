"""Safety that is always on, in front of every Arm backend.

Order of the filter: NaN/inf rejection -> joint limits -> per-step clamp (on by default).

Non-finite policy (decided here, documented in docs/hardware.md): a NaN or ±inf entry is *held*:
that actuator keeps its previously sent target, the others still move, and the event is counted
in ``SafetyFilter.stats`` (and logged once). Raising instead would hand a policy bug to the
caller's error handling mid-motion, and an unhandled exception ends in torque-off: the arm drops.
Holding is the state the firmware's own watchdog falls back to as well. ``on_nonfinite="raise"``
exists for tests and offline checks. A command of the wrong shape is a programming error and always
raises SafetyError.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from types import FrameType
from typing import Any, Protocol

import numpy as np

from hardware.errors import SafetyError
from hardware.spec import ArmSpec

log = logging.getLogger(__name__)

NONFINITE_POLICIES = ("hold", "raise")


@dataclass
class SafetyStats:
    commands: int = 0
    nonfinite: int = 0  # commands with at least one NaN/inf entry
    limit_clamped: int = 0  # commands with at least one entry outside the joint limits
    step_clamped: int = 0  # commands with at least one entry over the per-step clamp


class SafetyFilter:
    """Makes any policy output safe to send: finite, inside the limits, at most one step away."""

    def __init__(
        self,
        spec: ArmSpec,
        max_step_rad: float | None = None,
        on_nonfinite: str = "hold",
    ) -> None:
        if on_nonfinite not in NONFINITE_POLICIES:
            raise SafetyError(
                f"on_nonfinite {on_nonfinite!r} is not one of {', '.join(NONFINITE_POLICIES)}"
            )
        step = spec.safety.max_step_rad if max_step_rad is None else float(max_step_rad)
        if not np.isfinite(step) or step <= 0:
            raise SafetyError(
                f"max_step_rad must be a finite number > 0 (the clamp cannot be switched off), "
                f"got {max_step_rad!r}"
            )
        self.spec = spec
        self.n = spec.n_actuators
        self.lower_rad = spec.actuator_lower_rad.astype(float)
        self.upper_rad = spec.actuator_upper_rad.astype(float)
        self.max_step_rad = step
        self.on_nonfinite = on_nonfinite
        self.stats = SafetyStats()
        self._warned = False

    def clip_to_limits(self, q_rad: np.ndarray) -> np.ndarray:
        return np.clip(np.asarray(q_rad, dtype=float), self.lower_rad, self.upper_rad)

    def check_shape(self, targets_rad: Any) -> np.ndarray:
        try:
            q = np.asarray(targets_rad, dtype=float)
        except (TypeError, ValueError):
            raise SafetyError(
                f"targets must be {self.n} numbers ({', '.join(self.spec.actuator_names)}), "
                f"got {targets_rad!r}"
            ) from None
        if q.shape != (self.n,):
            raise SafetyError(
                f"targets must have shape ({self.n},) for actuators "
                f"{', '.join(self.spec.actuator_names)}, got shape {q.shape}"
            )
        return q

    def filter(self, targets_rad: Any, previous_sent_rad: np.ndarray) -> np.ndarray:
        """Safe targets (n_actuators,) given the last targets that actually went out."""
        q = self.check_shape(targets_rad)
        prev = np.asarray(previous_sent_rad, dtype=float)
        if prev.shape != (self.n,) or not np.all(np.isfinite(prev)):
            raise SafetyError(f"previous targets must be {self.n} finite numbers, got {prev!r}")
        prev = self.clip_to_limits(prev)
        self.stats.commands += 1
        bad = ~np.isfinite(q)
        if bad.any():
            self.stats.nonfinite += 1
            names = [n for n, b in zip(self.spec.actuator_names, bad, strict=True) if b]
            if self.on_nonfinite == "raise":
                raise SafetyError(f"non-finite target(s) for {', '.join(names)}: {q.tolist()}")
            if not self._warned:
                log.warning("non-finite target(s) for %s: holding them", ", ".join(names))
                self._warned = True
            q = np.where(bad, prev, q)
        limited = np.clip(q, self.lower_rad, self.upper_rad)
        if np.any(limited != q):
            self.stats.limit_clamped += 1
        stepped = np.clip(limited, prev - self.max_step_rad, prev + self.max_step_rad)
        if np.any(stepped != limited):
            self.stats.step_clamped += 1
        # prev is inside the limits, so a step towards a target inside the limits stays inside;
        # the final clip only guards against float rounding at the boundary.
        return np.clip(stepped, self.lower_rad, self.upper_rad)


class Watchdog:
    """Calls ``on_expire`` once when ``kick()`` has not been called for ``timeout_s``.

    The host-side twin of the firmware watchdog: it catches a control loop that stalls (a hung
    policy, a debugger breakpoint) on backends whose device has no watchdog of its own."""

    def __init__(
        self, timeout_s: float, on_expire: Callable[[], None], name: str = "watchdog"
    ) -> None:
        if not np.isfinite(timeout_s) or timeout_s <= 0:
            raise SafetyError(f"watchdog timeout must be > 0 s, got {timeout_s!r}")
        self.timeout_s = float(timeout_s)
        self._on_expire = on_expire
        self._name = name
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._deadline: float | None = None
        self._stop = False
        self._thread: threading.Thread | None = None
        self.fired = 0

    def arm(self) -> None:
        """Start (or restart) counting from now."""
        with self._lock:
            self._deadline = time.monotonic() + self.timeout_s
            if self._thread is None or not self._thread.is_alive():
                self._stop = False
                self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
                self._thread.start()
        self._wake.set()

    def kick(self) -> None:
        with self._lock:
            if self._deadline is not None:
                self._deadline = time.monotonic() + self.timeout_s

    def disarm(self) -> None:
        with self._lock:
            self._deadline = None
        self._wake.set()

    def stop(self) -> None:
        with self._lock:
            self._deadline = None
            self._stop = True
        self._wake.set()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=2.0)
        self._thread = None

    @property
    def armed(self) -> bool:
        return self._deadline is not None

    def _run(self) -> None:
        while True:
            with self._lock:
                if self._stop:
                    return
                deadline = self._deadline
            if deadline is None:
                self._wake.wait(1.0)
                self._wake.clear()
                continue
            remaining = deadline - time.monotonic()
            if remaining > 0:
                self._wake.wait(remaining)
                self._wake.clear()
                continue
            with self._lock:
                if self._deadline is None or self._deadline > time.monotonic():
                    continue
                self._deadline = None
            self.fired += 1
            try:
                self._on_expire()
            except Exception:  # the watchdog must survive a failing e-stop to report it
                log.exception("%s: e-stop handler failed", self._name)


class EStoppable(Protocol):
    def estop(self, reason: str) -> None: ...


@contextmanager
def estop_on_signals(
    arm: EStoppable, signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)
) -> Iterator[None]:
    """On SIGINT/SIGTERM inside the block: e-stop the arm (hold, then torque off), then leave as
    the signal would have (KeyboardInterrupt, or SystemExit(128 + signum)). Main thread only.

    The handler itself only raises: the e-stop runs as that exception leaves the block, after any
    serial transaction the signal interrupted has unwound (doing I/O inside the handler could
    re-enter a transaction that holds the port's lock and deadlock)."""
    previous: dict[int, Any] = {}
    fired: list[int] = []

    def handler(signum: int, frame: FrameType | None) -> None:
        fired.append(signum)
        for sig, prev in previous.items():
            signal.signal(sig, prev)
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise SystemExit(128 + signum)

    for sig in signals:
        previous[sig] = signal.signal(sig, handler)
    try:
        yield
    except BaseException:
        if fired:
            try:
                arm.estop(f"signal {signal.Signals(fired[0]).name}")
            except Exception:  # still leave with the signal's exception
                log.exception("e-stop after signal %s failed", fired[0])
        raise
    finally:
        for sig, prev in previous.items():
            if signal.getsignal(sig) is handler:
                signal.signal(sig, prev)
