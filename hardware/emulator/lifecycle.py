"""The lifecycle every emulated device on a pty shares: the Python firmware model
(``server.Emulator``) and the AVR binary in simavr (``avr.AvrEmulator``)."""

from __future__ import annotations

from pathlib import Path
from types import TracebackType
from typing import TypeVar

_D = TypeVar("_D", bound="PtyDevice")


class PtyDevice:
    """``start()`` opens the pty and serves; ``stop()`` ends it. A context manager; ``port`` is
    the path a host opens (the ``--link`` symlink when one was given)."""

    link: Path | None
    device_path: str
    _running: bool

    def start(self) -> str:
        raise NotImplementedError

    def stop(self) -> None:
        raise NotImplementedError

    def __enter__(self: _D) -> _D:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    @property
    def port(self) -> str:
        return str(self.link) if self.link is not None else self.device_path

    @property
    def running(self) -> bool:
        return self._running
