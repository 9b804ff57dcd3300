"""The mock hardware: emulated devices for all three protocols, served on a pseudo-terminal."""

from hardware.emulator.avr import AvrEmulator
from hardware.emulator.devices import DEVICES, EmulatedDevice
from hardware.emulator.dynamics import ServoBank, ServoParams
from hardware.emulator.firmware import AppliedCommand, FirmwareCore
from hardware.emulator.server import Emulator, EmulatorConfig, FaultConfig, pty_baud

FIRMWARES: dict[str, type[Emulator] | type[AvrEmulator]] = {
    "python": Emulator,  # the Python firmware model (every protocol, fault injection)
    "avr": AvrEmulator,  # the arm3 .elf in simavr (s2r only)
}
"""What serves an emulated arm, by name (``sim2real arm emulate --firmware``)."""

__all__ = [
    "DEVICES",
    "FIRMWARES",
    "AppliedCommand",
    "AvrEmulator",
    "EmulatedDevice",
    "Emulator",
    "EmulatorConfig",
    "FaultConfig",
    "FirmwareCore",
    "ServoBank",
    "ServoParams",
    "pty_baud",
]
