"""What an emulated arm offers the mock world's physics, which moves its horns.

Both emulated devices (the Python firmware model and the AVR binary) keep their servos in a
``ServoBank``. Attached to a body (``ServoBank.attach_body``), the bank computes each servo's drive
setpoint from the commands (latency, dead band, rate limit) and the body (MuJoCo's
torque-limited position actuators, with gravity and contacts) decides where the horns go; the
readings come from there, as a real servo's potentiometer reads its real horn.
"""

from __future__ import annotations

import threading

import numpy as np

from hardware.errors import HardwareError
from hardware.servo_model import ServoBank
from hardware.spec import ArmSpec


class BodyCoupling:
    """Thread-safe access to the servos for a body that moves them; emulators mix it in."""

    servos: ServoBank
    spec: ArmSpec
    _lock: threading.RLock

    def jam(self, *names: str) -> None:
        """Jam the named actuators where their horns are now (the mock can jam a servo): they
        stop moving whatever they are told, and push against the jam while powered. ``jam()``
        with no names frees every servo."""
        valid = self.spec.actuator_names
        unknown = [n for n in names if n not in valid]
        if unknown:
            raise HardwareError(f"cannot jam {unknown}: valid actuators are {list(valid)}")
        with self._lock:
            self._catch_up()
            self.servos.jam(np.array([n in names for n in valid], dtype=bool))

    def _catch_up(self) -> None:
        """Integrate the servos up to now before anyone looks (lock held). Default: the
        emulator integrates on its own events and has nothing to catch up."""

    def attach_body(self) -> None:
        with self._lock:
            self._catch_up()
            self.servos.attach_body()

    def setpoints_rad(self) -> np.ndarray:
        """What each servo drives its horn towards now (n_actuators,), physical rad."""
        with self._lock:
            self._catch_up()
            return self.servos.pos.copy()

    def sense(self, body_rad: np.ndarray, body_vel_rad_s: np.ndarray) -> None:
        """Where the body holds the horns now (n_actuators,), physical rad and rad/s."""
        with self._lock:
            self._catch_up()
            self.servos.sense(body_rad, body_vel_rad_s)

    def true_positions_rad(self) -> np.ndarray:
        """The PHYSICAL joint angles (n_actuators,): where the horns really are, for rendering
        and for tests. With a plant's joint offsets (``hardware.plant``) the host reads
        ``physical - offset``; a mock world renders these angles with the plant's links."""
        with self._lock:
            self._catch_up()
            return self.servos.horn_rad.copy()
