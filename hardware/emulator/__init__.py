"""The mock hardware: emulated devices for all three protocols, served on a pseudo-terminal."""

from hardware.emulator.devices import DEVICES, EmulatedDevice
from hardware.emulator.dynamics import ServoBank, ServoParams
from hardware.emulator.firmware import AppliedCommand, FirmwareCore
from hardware.emulator.server import Emulator, EmulatorConfig, FaultConfig, pty_baud

__all__ = [
    "DEVICES",
    "AppliedCommand",
    "EmulatedDevice",
    "Emulator",
    "EmulatorConfig",
    "FaultConfig",
    "FirmwareCore",
    "ServoBank",
    "ServoParams",
    "pty_baud",
]
