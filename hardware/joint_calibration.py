"""Joint calibration: the map between servo units and the simulation's joint angles.

Every actuator gets ``units = offset_units + direction * scale_units_per_rad * angle_rad``. The
offset is the servo reading when the joint sits at the simulation's zero pose, the direction fixes
servos mounted the other way round (the "reversed joint" LeRobot users hit most), and the scale
converts radians into the protocol's unit (µs of pulse, encoder counts, quarter-µs).

Files are YAML (through ``hardware.yamlio``), one per arm id, written atomically, so a crash while
saving never leaves half a calibration behind.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hardware import yamlio
from hardware.errors import CalibrationFileError, SpecError, YamlError
from hardware.spec import ArmSpec

CALIBRATION_DIR_ENV = "SIM2REAL_CALIBRATION_DIR"
_UNIT_EPS = 1e-6  # units; float noise allowed when rounding limits inward


@dataclass(frozen=True)
class UnitFrame:
    """A protocol's servo unit: its name, full range and nominal centre and scale."""

    units: str  # "us", "counts", "qus"
    unit_min: int
    unit_max: int
    center_units: float  # reading at the servo's mechanical centre
    units_per_rad: float

    def __post_init__(self) -> None:
        if self.unit_min >= self.unit_max:
            raise SpecError(f"unit range [{self.unit_min}, {self.unit_max}] is empty")
        if not math.isfinite(self.units_per_rad) or self.units_per_rad <= 0:
            raise SpecError(f"units_per_rad must be > 0, got {self.units_per_rad!r}")


@dataclass(frozen=True)
class JointCalibration:
    """One actuator: servo units = offset + direction * scale * angle."""

    name: str
    offset_units: float
    direction: int
    scale_units_per_rad: float

    def __post_init__(self) -> None:
        if self.direction not in (1, -1):
            raise CalibrationFileError(
                f"joint {self.name}: direction must be 1 or -1, got {self.direction!r}"
            )
        for key in ("offset_units", "scale_units_per_rad"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise CalibrationFileError(
                    f"joint {self.name}: {key} must be a number, got {value!r}"
                )
            if not math.isfinite(value):
                raise CalibrationFileError(
                    f"joint {self.name}: {key} must be finite, got {value!r}"
                )
        if self.scale_units_per_rad <= 0:
            raise CalibrationFileError(
                f"joint {self.name}: scale_units_per_rad must be > 0, got {self.scale_units_per_rad!r}"
            )


@dataclass(frozen=True)
class ArmCalibration:
    """All actuators of one arm, in ``spec.actuator_names`` order, for one protocol's units."""

    arm_id: str
    protocol: str
    frame: UnitFrame
    joints: tuple[JointCalibration, ...]

    def __post_init__(self) -> None:
        if not self.arm_id or not self.arm_id.replace("-", "").replace("_", "").isalnum():
            raise CalibrationFileError(
                f"arm id must be letters, digits, '-' or '_', got {self.arm_id!r}"
            )
        if not self.joints:
            raise CalibrationFileError("a calibration needs at least one joint")

    # ---- vectors --------------------------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def offset_units(self) -> np.ndarray:  # (n_actuators,)
        return np.array([j.offset_units for j in self.joints], dtype=float)

    @property
    def direction(self) -> np.ndarray:  # (n_actuators,)
        return np.array([j.direction for j in self.joints], dtype=float)

    @property
    def scale_units_per_rad(self) -> np.ndarray:  # (n_actuators,)
        return np.array([j.scale_units_per_rad for j in self.joints], dtype=float)

    def to_units_float(self, angles_rad: np.ndarray) -> np.ndarray:
        """Exact (unrounded) servo units for angles; (n,) -> (n,)."""
        q = np.asarray(angles_rad, dtype=float)
        return self.offset_units + self.direction * self.scale_units_per_rad * q

    def to_units(self, angles_rad: np.ndarray) -> np.ndarray:
        """Integer servo units (rounded to nearest), clipped to the servo's range; (n,) int64."""
        u = np.rint(self.to_units_float(angles_rad))
        return np.clip(u, self.frame.unit_min, self.frame.unit_max).astype(np.int64)

    def from_units(self, units: np.ndarray) -> np.ndarray:
        """Angles in rad for servo units; (n,) -> (n,) float."""
        u = np.asarray(units, dtype=float)
        return self.direction * (u - self.offset_units) / self.scale_units_per_rad

    def unit_limits(self, spec: ArmSpec) -> tuple[np.ndarray, np.ndarray]:
        """Joint limits in integer units, rounded *inward* so every unit value decodes inside
        the rad limits. Raises SpecError (naming the joint) when a limit is outside the servo's
        unit range: then the arm could be asked for a pose the servo cannot reach."""
        self.check_spec(spec)
        a = self.to_units_float(spec.actuator_lower_rad)
        b = self.to_units_float(spec.actuator_upper_rad)
        lo_f, hi_f = np.minimum(a, b), np.maximum(a, b)
        for i, name in enumerate(self.names):
            if (
                lo_f[i] < self.frame.unit_min - _UNIT_EPS
                or hi_f[i] > self.frame.unit_max + _UNIT_EPS
            ):
                raise SpecError(
                    f"joint {name}: limits [{spec.actuator_lower_rad[i]:.4f}, "
                    f"{spec.actuator_upper_rad[i]:.4f}] rad map to [{lo_f[i]:.1f}, {hi_f[i]:.1f}] "
                    f"{self.frame.units}, outside the servo range [{self.frame.unit_min}, "
                    f"{self.frame.unit_max}] {self.frame.units}"
                )
        lo = np.ceil(lo_f - _UNIT_EPS).astype(np.int64)
        hi = np.floor(hi_f + _UNIT_EPS).astype(np.int64)
        return lo, hi

    def max_step_units(self, max_step_rad: float) -> np.ndarray:
        """The per-command clamp in units, rounded down so it never exceeds ``max_step_rad``."""
        return np.floor(max_step_rad * self.scale_units_per_rad + _UNIT_EPS).astype(np.int64)

    def check_spec(self, spec: ArmSpec) -> None:
        """The calibration must name the spec's actuators in the spec's order."""
        if self.names != spec.actuator_names:
            raise CalibrationFileError(
                f"calibration {self.arm_id!r} has joints {list(self.names)}, but spec "
                f"{spec.name!r} has actuators {list(spec.actuator_names)}"
            )

    # ---- io -------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "arm_id": self.arm_id,
            "protocol": self.protocol,
            "units": self.frame.units,
            "unit_min": self.frame.unit_min,
            "unit_max": self.frame.unit_max,
            "center_units": float(self.frame.center_units),
            "units_per_rad": float(self.frame.units_per_rad),
            "joints": [
                {
                    "name": j.name,
                    "offset_units": float(j.offset_units),
                    "direction": int(j.direction),
                    "scale_units_per_rad": float(j.scale_units_per_rad),
                }
                for j in self.joints
            ],
        }

    @classmethod
    def from_dict(cls, data: Any, source: str = "calibration") -> ArmCalibration:
        if not isinstance(data, dict):
            raise CalibrationFileError(f"{source}: expected a mapping, got {type(data).__name__}")
        required = {"arm_id", "protocol", "units", "unit_min", "unit_max", "joints"}
        allowed = required | {"center_units", "units_per_rad"}
        missing = sorted(required - set(data))
        if missing:
            raise CalibrationFileError(f"{source}: missing key(s) {missing}")
        unknown = sorted(set(data) - allowed)
        if unknown:
            raise CalibrationFileError(
                f"{source}: unknown key(s) {unknown}; valid: {sorted(allowed)}"
            )
        joints_raw = data["joints"]
        if not isinstance(joints_raw, list) or not joints_raw:
            raise CalibrationFileError(f"{source}: 'joints' must be a non-empty list")
        try:
            joints = []
            fields = {"name", "offset_units", "direction", "scale_units_per_rad"}
            for k, raw in enumerate(joints_raw):
                if not isinstance(raw, dict) or set(raw) != fields:
                    raise CalibrationFileError(
                        f"joint #{k}: expected keys {sorted(fields)}, got {raw!r}"
                    )
                joints.append(
                    JointCalibration(
                        name=str(raw["name"]),
                        offset_units=raw["offset_units"],
                        direction=raw["direction"],
                        scale_units_per_rad=raw["scale_units_per_rad"],
                    )
                )
            for key in ("unit_min", "unit_max"):
                if isinstance(data[key], bool) or not isinstance(data[key], int):
                    raise CalibrationFileError(f"{key} must be an integer, got {data[key]!r}")
            scale = float(np.mean([j.scale_units_per_rad for j in joints]))
            frame = UnitFrame(
                units=str(data["units"]),
                unit_min=data["unit_min"],
                unit_max=data["unit_max"],
                center_units=float(
                    data.get("center_units", (data["unit_min"] + data["unit_max"]) / 2)
                ),
                units_per_rad=float(data.get("units_per_rad", scale)),
            )
            return cls(
                arm_id=str(data["arm_id"]),
                protocol=str(data["protocol"]),
                frame=frame,
                joints=tuple(joints),
            )
        except (CalibrationFileError, SpecError, TypeError, ValueError) as exc:
            raise CalibrationFileError(f"{source}: {exc}") from None

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write atomically (temp file + os.replace); returns the path."""
        target = Path(path)
        header = (
            f"sim2real joint calibration for arm {self.arm_id} ({self.protocol}, "
            f"{self.frame.units})\nunits = offset_units + direction * scale_units_per_rad * "
            "angle_rad; angle 0 is the simulation's zero pose"
        )
        yamlio.dump(target, self.to_dict(), header=header)
        return target

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> ArmCalibration:
        """Read a calibration file; every failure is one CalibrationFileError naming the file."""
        p = Path(path)
        if not p.is_file():
            raise CalibrationFileError(
                f"no calibration file {str(p)!r}; run `sim2real arm calibrate` to create one"
            )
        try:
            data = yamlio.load(p)
        except YamlError as exc:
            raise CalibrationFileError(f"corrupt calibration YAML: {exc}") from None
        return cls.from_dict(data, source=str(p))

    def check_protocol(self, protocol: str, frame: UnitFrame) -> None:
        """A calibration only makes sense for the units it was measured in."""
        if self.protocol != protocol or self.frame.units != frame.units:
            raise CalibrationFileError(
                f"calibration {self.arm_id!r} is for protocol {self.protocol} "
                f"({self.frame.units}), but the arm uses {protocol} ({frame.units})"
            )


def nominal_calibration(
    spec: ArmSpec, protocol: str, frame: UnitFrame, arm_id: str | None = None
) -> ArmCalibration:
    """The datasheet mapping: servo centre at angle 0, direction +1, nominal scale.

    Good enough to start; ``sim2real arm calibrate`` measures the real offsets and directions."""
    joints = tuple(
        JointCalibration(
            name=name,
            offset_units=float(frame.center_units),
            direction=1,
            scale_units_per_rad=float(frame.units_per_rad),
        )
        for name in spec.actuator_names
    )
    return ArmCalibration(arm_id=arm_id or spec.name, protocol=protocol, frame=frame, joints=joints)


def with_joints(
    calibration: ArmCalibration,
    offsets_units: Sequence[float] | None = None,
    directions: Sequence[int] | None = None,
    scales_units_per_rad: Sequence[float] | None = None,
    arm_id: str | None = None,
) -> ArmCalibration:
    """A copy with some per-joint values replaced (the emulator's mounting, test fixtures)."""
    n = len(calibration.joints)
    offs = list(offsets_units) if offsets_units is not None else list(calibration.offset_units)
    dirs = list(directions) if directions is not None else [j.direction for j in calibration.joints]
    scales = (
        list(scales_units_per_rad)
        if scales_units_per_rad is not None
        else list(calibration.scale_units_per_rad)
    )
    if not len(offs) == len(dirs) == len(scales) == n:
        raise CalibrationFileError(
            f"expected {n} values per joint, got offsets {len(offs)}, directions {len(dirs)}, "
            f"scales {len(scales)}"
        )
    joints = tuple(
        JointCalibration(j.name, float(o), int(d), float(s))
        for j, o, d, s in zip(calibration.joints, offs, dirs, scales, strict=True)
    )
    return ArmCalibration(
        arm_id=arm_id or calibration.arm_id,
        protocol=calibration.protocol,
        frame=calibration.frame,
        joints=joints,
    )


def calibration_dir(root: str | os.PathLike[str] | None = None) -> Path:
    """Where per-arm calibration files live: ``root``, $SIM2REAL_CALIBRATION_DIR, or
    ~/.config/sim2real/arms."""
    if root is not None:
        return Path(root)
    env = os.environ.get(CALIBRATION_DIR_ENV)
    if env:
        return Path(env)
    return Path.home() / ".config" / "sim2real" / "arms"


def calibration_path(arm_id: str, root: str | os.PathLike[str] | None = None) -> Path:
    if not arm_id or not arm_id.replace("-", "").replace("_", "").isalnum():
        raise CalibrationFileError(f"arm id must be letters, digits, '-' or '_', got {arm_id!r}")
    return calibration_dir(root) / f"{arm_id}.yaml"


def fit_joint(
    name: str,
    units_at_zero: float,
    units_at_reference: float,
    reference_rad: float,
) -> JointCalibration:
    """Offset, direction and scale from two readings: at angle 0 and at ``reference_rad``."""
    if not math.isfinite(reference_rad) or abs(reference_rad) < 1e-3:
        raise CalibrationFileError(
            f"joint {name}: reference angle must be non-zero, got {reference_rad!r} rad"
        )
    slope = (units_at_reference - units_at_zero) / reference_rad
    if abs(slope) < 1e-6:
        raise CalibrationFileError(
            f"joint {name}: the two readings are equal ({units_at_zero}); the joint did not move"
        )
    return JointCalibration(
        name=name,
        offset_units=float(units_at_zero),
        direction=1 if slope > 0 else -1,
        scale_units_per_rad=float(abs(slope)),
    )
