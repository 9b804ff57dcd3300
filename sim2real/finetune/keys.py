"""Terminal keys for a human beside a learning arm: pause, e-stop, mark success, confirm a reset.

A person watching a real arm sees what its cameras cannot judge (a cube that slipped, a target
the arm hides) and must be able to stop it at once. ``HumanKeys`` reads single key presses from
a tty in cbreak mode (no Enter needed, Ctrl-C still signals) in its own thread, so the control
loop never waits for the keyboard. Every intervention is recorded with its monotonic time (to
line up with the loop's log) and its UTC time (to line up with a person's notes). The terminal's
settings are restored on ``stop()``, on leaving the ``with`` block whatever raised, and at
interpreter exit.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import os
import select
import termios
import threading
import time
import tty
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from datetime import datetime, timezone
from types import TracebackType
from typing import Any

from sim2real.errors import ConfigError

log = logging.getLogger(__name__)

# What a key does (one registry; help text and handling both come from it).
PAUSE, ESTOP, SUCCESS, FAILURE, RESET_DONE = "pause", "estop", "success", "failure", "reset_done"
RESUME = "resume"  # recorded when a paused run is resumed by the pause key
KEYS: Mapping[bytes, str] = {
    b" ": PAUSE,  # space: pause, and again to resume
    b"p": PAUSE,
    b"e": ESTOP,
    b"s": SUCCESS,
    b"f": FAILURE,
    b"r": RESET_DONE,
    b"\n": RESET_DONE,  # Enter: "the table is ready"
    b"\r": RESET_DONE,
}
HELP = "keys: space/p pause-resume · e e-stop · s success · f failure · r/Enter reset done"


@dataclass(frozen=True)
class Intervention:
    """One key a person pressed, and when."""

    action: str  # pause, resume, estop, success, failure, reset_done
    key: str  # the key as typed (repr-safe)
    monotonic_s: float  # time.monotonic(): the loop's clock
    utc: str  # ISO 8601, UTC

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class HumanKeys:
    """Reads keys from ``fd`` (default: stdin) in cbreak mode on its own thread.

    ``on_estop(reason)`` is called on the key thread the moment ``e`` is pressed (pass the arm's
    ``estop``); the learner's side polls ``paused``, ``estopped``, ``take_mark()`` and
    ``wait_for_reset()``."""

    def __init__(
        self,
        fd: int | None = None,
        on_estop: Callable[[str], None] | None = None,
        keys: Mapping[bytes, str] = KEYS,
    ) -> None:
        self.fd = 0 if fd is None else fd
        if not os.isatty(self.fd):
            raise ConfigError(
                f"human-in-the-loop keys need a terminal; fd {self.fd} is not a tty "
                "(run in a terminal, not with input redirected)"
            )
        self.on_estop = on_estop
        self.keys = dict(keys)
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        self._interventions: list[Intervention] = []
        self._paused = False
        self._estopped = False
        self._mark: bool | None = None
        self._reset_done = False
        self._saved: list[Any] | None = None
        self._wake_r, self._wake_w = -1, -1
        self._thread: threading.Thread | None = None

    # ---- lifecycle ------------------------------------------------------------------------
    def start(self) -> HumanKeys:
        if self._thread is not None:
            return self
        self._saved = termios.tcgetattr(self.fd)
        atexit.register(self._restore)
        tty.setcbreak(self.fd, termios.TCSANOW)
        self._wake_r, self._wake_w = os.pipe()
        self._thread = threading.Thread(target=self._run, name="human-keys", daemon=True)
        self._thread.start()
        log.info(HELP)
        return self

    def stop(self) -> None:
        """Stop reading and restore the terminal (safe to call twice)."""
        try:
            if self._thread is not None:
                os.write(self._wake_w, b"x")
                self._thread.join(timeout=5.0)
                self._thread = None
        finally:
            self._restore()
            for end in (self._wake_r, self._wake_w):
                if end >= 0:
                    with contextlib.suppress(OSError):
                        os.close(end)
            self._wake_r = self._wake_w = -1

    def _restore(self) -> None:
        saved, self._saved = self._saved, None
        if saved is not None:
            with contextlib.suppress(termios.error, OSError):
                termios.tcsetattr(self.fd, termios.TCSADRAIN, saved)
            atexit.unregister(self._restore)

    def __enter__(self) -> HumanKeys:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    # ---- the key thread -------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            try:
                ready, _, _ = select.select([self.fd, self._wake_r], [], [])
            except (OSError, ValueError):
                return
            if self._wake_r in ready:
                return
            try:
                data = os.read(self.fd, 64)
            except OSError:  # the terminal went away (hang-up): nothing more to read
                return
            if not data:
                return
            for i in range(len(data)):
                self.press(data[i : i + 1])

    def press(self, key: bytes) -> Intervention | None:
        """Handle one key (the key thread calls this; unknown keys are ignored)."""
        action = self.keys.get(key.lower())
        if action is None:
            return None
        now = time.monotonic()
        utc = datetime.now(timezone.utc).isoformat(timespec="milliseconds")
        if action == ESTOP:
            # the flag before the arm's e-stop returns: whoever the latched arm refuses (a
            # learner's step blocked on the arm's lock during the hold) already sees why
            self._estopped = True
        if action == ESTOP and self.on_estop is not None:  # first: the arm stops at once
            try:
                self.on_estop("e-stop key")
            except Exception as exc:  # the arm may be gone; the flag still stops the run
                log.error("e-stop callback failed: %s", exc)
        with self._changed:
            if action == PAUSE and self._paused:
                action = RESUME
            record = Intervention(action, key.decode("latin-1"), now, utc)
            self._interventions.append(record)
            if action in (PAUSE, RESUME):
                self._paused = action == PAUSE
            elif action == ESTOP:
                self._estopped = True
            elif action in (SUCCESS, FAILURE):
                self._mark = action == SUCCESS
            elif action == RESET_DONE:
                self._reset_done = True
            self._changed.notify_all()
        log.warning("human: %s at %s (monotonic %.3f s)", action, utc, now)
        return record

    # ---- what the learner's side reads ----------------------------------------------------
    @property
    def interventions(self) -> list[Intervention]:
        with self._lock:
            return list(self._interventions)

    @property
    def paused(self) -> bool:
        return self._paused

    @property
    def estopped(self) -> bool:
        return self._estopped

    def clear_estop(self) -> None:
        """After a person has looked at the arm and restarted the run."""
        with self._lock:
            self._estopped = False

    def take_mark(self) -> bool | None:
        """The person's verdict on the episode in flight (True success, False failure, None
        none given), cleared by reading it."""
        with self._lock:
            mark, self._mark = self._mark, None
            return mark

    def wait_for(
        self, predicate: Callable[[], bool], hold: Callable[[], object] | None, period_s: float,
        timeout_s: float | None = None,
    ) -> bool:  # fmt: skip
        """Block until ``predicate()`` (read under the lock) holds, calling ``hold()`` every
        ``period_s`` meanwhile (the arm's watchdogs stay fed); False on timeout or e-stop."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            with self._changed:
                if predicate():
                    return True
                if self._estopped:
                    return False
                wait = period_s
                if deadline is not None:
                    wait = min(wait, deadline - time.monotonic())
                    if wait <= 0:
                        return False
                self._changed.wait(wait)
            if hold is not None:
                hold()

    def wait_while_paused(self, hold: Callable[[], object] | None, period_s: float) -> bool:
        """Hold the arm while paused; False if an e-stop came instead of a resume."""
        return self.wait_for(lambda: not self._paused, hold, period_s)

    def wait_for_reset(
        self, hold: Callable[[], object] | None, period_s: float, timeout_s: float | None = None
    ) -> bool:
        """Block until the person confirms the table is ready (``r``/Enter), then clear it."""
        ok = self.wait_for(lambda: self._reset_done, hold, period_s, timeout_s)
        with self._lock:
            self._reset_done = False
        return ok
