"""Hardware abstraction for a serial servo arm: numpy, pyserial and PyYAML only (the core
install, no extra), so it runs on a Raspberry Pi beside the arm."""

from hardware.errors import HardwareError, SpecError
from hardware.spec import ArmSpec, load_spec

__all__ = ["ArmSpec", "HardwareError", "SpecError", "load_spec"]
