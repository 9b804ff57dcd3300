"""Exceptions of the simulation/training side; messages name the value and the valid choices."""

from __future__ import annotations

import signal
from collections.abc import Iterable


class Sim2RealError(Exception):
    """Base class: the CLI prints these as one line and exits non-zero."""


class UnknownNameError(Sim2RealError, KeyError):
    """A name that is not in a registry."""

    def __init__(self, kind: str, name: str, valid: Iterable[str]) -> None:
        self.kind, self.name, self.valid = kind, name, sorted(valid)
        super().__init__(f"unknown {kind} {name!r}; valid: {', '.join(self.valid)}")

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


class ConfigError(Sim2RealError, ValueError):
    """A configuration value is out of range or inconsistent."""


class RunDirError(Sim2RealError):
    """A run directory is missing, incomplete or corrupt."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C so the same cleanup runs (``cli.signals`` raises it; the
    library tells the two apart by this type, so it lives below the CLI)."""

    def __init__(self, signum: int = signal.SIGTERM) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum
