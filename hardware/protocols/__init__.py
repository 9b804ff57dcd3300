"""One registry of servo protocols: the name a user types -> the host-side driver class."""

from __future__ import annotations

from hardware.errors import HardwareError
from hardware.protocols.base import DeviceInfo, Framer, Link, Protocol, UnitState
from hardware.protocols.feetech import FeetechProtocol
from hardware.protocols.maestro import MaestroProtocol
from hardware.protocols.s2r import S2RProtocol

PROTOCOLS: dict[str, type[Protocol]] = {
    S2RProtocol.name: S2RProtocol,
    FeetechProtocol.name: FeetechProtocol,
    MaestroProtocol.name: MaestroProtocol,
}


def get_protocol(name: str) -> type[Protocol]:
    """The driver class for ``name``; the error lists the valid names."""
    try:
        return PROTOCOLS[name]
    except KeyError:
        raise HardwareError(
            f"unknown protocol {name!r}; valid: {', '.join(sorted(PROTOCOLS))}"
        ) from None


__all__ = [
    "PROTOCOLS",
    "DeviceInfo",
    "FeetechProtocol",
    "Framer",
    "Link",
    "MaestroProtocol",
    "Protocol",
    "S2RProtocol",
    "UnitState",
    "get_protocol",
]
