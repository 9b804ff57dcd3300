"""Helpers: an ArmProbe over the emulator's log and true state, and a SerialArm+emulator pair."""

from __future__ import annotations

import numpy as np
from timescale import scaled

from hardware.emulator import Emulator
from hardware.joint_calibration import ArmCalibration

# how long the probe waits for the emulator to take in the host's last bytes (a loaded machine
# may keep its thread off the CPU a while): a bound, not a wait
SYNC_TIMEOUT_S = scaled(10.0)


class EmulatorProbe:
    """Ground truth from the emulator: true joint angles, torque, and every target it applied,
    decoded through ``calibration`` (the emulator's true mounting in these tests)."""

    def __init__(self, emulator: Emulator, calibration: ArmCalibration) -> None:
        self.emulator = emulator
        self.calibration = calibration

    def true_positions_rad(self) -> np.ndarray:
        return self.emulator.true_positions_rad()

    def torque_enabled(self) -> bool:
        self.emulator.sync(SYNC_TIMEOUT_S)
        return bool(np.all(self.emulator.torque_enabled()))

    def received_units(self) -> list[np.ndarray]:
        """Target vectors in device units, rebuilt from per-servo log entries where needed."""
        self.emulator.sync(SYNC_TIMEOUT_S)
        ids = list(self.emulator.spec.actuator_ids)
        out: list[np.ndarray] = []
        current: dict[int, int] = {}
        for e in self.emulator.applied("targets"):
            for sid, value in zip(e.ids, e.requested, strict=True):
                if value != 0 or self.emulator.protocol != "maestro":  # 0 = Maestro "off"
                    current[sid] = value
            if e.ids[-1] == ids[-1] and all(s in current for s in ids):
                out.append(np.array([current[s] for s in ids], dtype=np.int64))
        return out

    def received_targets_rad(self) -> list[np.ndarray]:
        return [self.calibration.from_units(u) for u in self.received_units()]
