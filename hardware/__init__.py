"""Hardware abstraction for a serial servo arm: numpy + pyserial only, so it runs on a Pi."""

from hardware.errors import HardwareError, SpecError
from hardware.spec import ArmSpec, load_spec

__all__ = ["ArmSpec", "HardwareError", "SpecError", "load_spec"]
