"""The emulator's servo dynamics: the one servo model in continuous time.

The physics lives in ``hardware.servo_model`` (shared with sim actuation and sysid); this module
keeps the names the emulator and its callers import.
"""

from hardware.servo_model import ServoBank, ServoParams

__all__ = ["ServoBank", "ServoParams"]
