"""SIGTERM handled as Ctrl-C, for the commands that run long (train, compare, deploy).

A scheduler, a container stop or ``kill`` sends SIGTERM; by default Python dies on it at once and
the work since the last checkpoint is lost. Inside ``interrupts_as_keyboard()`` SIGTERM raises
``Terminated``, a ``KeyboardInterrupt``, so every ``except KeyboardInterrupt`` that already keeps a
checkpoint (train), parks the arm and keeps the log (deploy) or stops workers (compare) handles it
the same way, and the command exits with 128 + the signal: 130 for SIGINT, 143 for SIGTERM.

SIGINT gets the same handler even where the process inherited it ignored: a background job of a
non-interactive shell starts with SIGINT ignored, and Python then never raises KeyboardInterrupt.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from types import FrameType
from typing import Any

from sim2real.errors import Terminated

__all__ = ["SIGNALS", "Received", "Terminated", "exit_code_for", "interrupts_as_keyboard"]

SIGNALS = (signal.SIGINT, signal.SIGTERM)


@dataclass
class Received:
    """The signals that arrived inside the block, first first."""

    signums: list[int] = field(default_factory=list)

    @property
    def exit_code(self) -> int | None:
        """128 + the first signal (the shell's convention), or None if none arrived."""
        return 128 + self.signums[0] if self.signums else None


def exit_code_for(exc: KeyboardInterrupt) -> int:
    """143 for a SIGTERM turned into ``Terminated``, 130 for Ctrl-C."""
    return 128 + (exc.signum if isinstance(exc, Terminated) else signal.SIGINT)


@contextmanager
def interrupts_as_keyboard() -> Iterator[Received]:
    """Inside the block SIGINT raises KeyboardInterrupt and SIGTERM raises ``Terminated``; the
    previous handlers come back afterwards. It yields what arrived, so a command whose loop
    swallows the interrupt (deploy stops cleanly and returns) still exits with 130/143.

    Signal handlers can only be set from the main thread; elsewhere this does nothing."""
    received = Received()
    if threading.current_thread() is not threading.main_thread():
        yield received
        return

    def handler(signum: int, frame: FrameType | None) -> None:
        received.signums.append(signum)
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise Terminated(signum)

    previous: dict[int, Any] = {}
    try:
        for sig in SIGNALS:
            previous[sig] = signal.signal(sig, handler)
        yield received
    finally:
        for signum, prev in previous.items():
            signal.signal(signum, prev)
