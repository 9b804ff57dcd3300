"""Exceptions of the hardware layer.

Every message names the offending value and, where there is a fixed set, the valid choices, so
the CLI can print it as one line and exit non-zero.
"""

from __future__ import annotations


class HardwareError(Exception):
    """Base class: anything the hardware layer refuses or cannot do."""


class SpecError(HardwareError, ValueError):
    """An ArmSpec (or its YAML) is malformed or physically inconsistent."""


class YamlError(SpecError):
    """A YAML document is outside the subset the hardware layer reads."""


class PortError(HardwareError):
    """A serial port is missing, busy, not permitted, or went away mid-session."""


class NoReplyError(HardwareError):
    """The device did not answer within the timeout after every retry."""


class ProtocolError(HardwareError):
    """The device answered, but with an error code or a reply that makes no sense."""


class DeviceResetError(HardwareError):
    """The device rebooted (brown-out, watchdog, USB reset): its torque is off."""


class SafetyError(HardwareError, ValueError):
    """A command was refused by the safety layer (wrong shape, torque off, e-stop latched)."""


class TorqueOffError(SafetyError):
    """A command while the torque is off: never enabled, disabled, or switched off under the
    host by the firmware's watchdog (a host that stopped talking)."""


class NotConnectedError(HardwareError):
    """An Arm method that needs the device was called before connect() or after close()."""


class CalibrationFileError(HardwareError):
    """A joint-calibration YAML is missing, corrupt, or does not fit the spec."""


class StallError(HardwareError):
    """A measured joint stopped following its command for longer than the servo model allows:
    the arm was held, then parked slowly (or, where it could not move, its torque cut)."""
