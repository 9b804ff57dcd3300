"""A plant: the arm as it really is, which is not the spec the user believes.

A plant file is an ArmSpec YAML (same schema; its ``servo:`` and ``links:`` figures are the
truth) plus an optional top-level ``plant:`` mapping of defects no spec field describes::

    plant:
      joint_offset_rad:                  # the horn sits this far off (joint name: rad)
        elbow: 0.2513
      command_latency_s: 0.05            # extra dead time between a frame and the servo acting
      droop_rad: 0.02                    # sag of the pitch joints while powered
      noise_rad: 0.002                   # std of the position reading

``joint_offset_rad`` follows one convention everywhere (here, kinematic DR, kinematic
calibration): **physical angle = servo reading + offset**. A servo commanded to ``q`` drives its
joint to ``q + offset`` and, sitting there, reads ``q``: a horn pressed on one spline tooth off.

The mock backend builds its emulator from a plant (``Plant.emulator``): the servo dynamics come
from ``plant.spec.servo``, droop/latency/noise from the ``plant:`` mapping, and the offsets from
the emulator's *mounting* calibration, which the host never sees. ``Emulator.true_positions_rad``
then returns PHYSICAL joint angles, which is what a mock world must render with ``plant.spec``'s
links. The policy, observation builder and safety keep the user's spec.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hardware import yamlio
from hardware.errors import SpecError
from hardware.spec import ArmSpec

if TYPE_CHECKING:
    from hardware.emulator.server import Emulator, EmulatorConfig
    from hardware.joint_calibration import ArmCalibration

PLANT_DIR = Path(__file__).with_name("specs") / "plants"
PLANT_KEY = "plant"
_DEFECT_KEYS = ("joint_offset_rad", "command_latency_s", "droop_rad", "noise_rad")


def _number(source: str, key: str, value: Any, *, non_negative: bool) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SpecError(f"{source}: {key} must be a number, got {value!r}")
    out = float(value)
    if not math.isfinite(out):
        raise SpecError(f"{source}: {key} must be finite, got {value!r}")
    if non_negative and out < 0:
        raise SpecError(f"{source}: {key} must be >= 0, got {value!r}")
    return out


@dataclass(frozen=True)
class Plant:
    """The truth about one arm: its spec and the defects the spec has no field for."""

    spec: ArmSpec
    joint_offset_rad: tuple[tuple[str, float], ...] = ()  # (joint name, rad), physical - reading
    command_latency_s: float = 0.0
    droop_rad: float = 0.0
    noise_rad: float = 0.0
    source: str = field(default="plant", compare=False)

    def __post_init__(self) -> None:
        src = self.source
        names = set(self.spec.joint_names)
        seen: set[str] = set()
        for name, value in self.joint_offset_rad:
            if name not in names:
                raise SpecError(
                    f"{src}: plant.joint_offset_rad names joint {name!r}, which spec "
                    f"{self.spec.name!r} does not have; valid: {list(self.spec.joint_names)}"
                )
            if name in seen:
                raise SpecError(f"{src}: plant.joint_offset_rad names {name!r} twice")
            seen.add(name)
            _number(src, f"plant.joint_offset_rad.{name}", value, non_negative=False)
            if abs(value) > math.pi / 2:
                raise SpecError(
                    f"{src}: plant.joint_offset_rad.{name} {value!r} is more than pi/2 rad: "
                    "that is a joint mounted the wrong way, not an offset"
                )
        for key in ("command_latency_s", "droop_rad", "noise_rad"):
            _number(src, f"plant.{key}", getattr(self, key), non_negative=True)

    # ---- values -----------------------------------------------------------------------------
    @classmethod
    def nominal(cls, spec: ArmSpec) -> Plant:
        """The arm exactly as specified (what the mock backend used before plants existed)."""
        return cls(spec=spec, source=f"spec {spec.name}")

    def offsets_rad(self) -> np.ndarray:
        """(n_actuators,) physical - reading, in ``spec.actuator_names`` order (gripper 0)."""
        given = dict(self.joint_offset_rad)
        return np.array([given.get(n, 0.0) for n in self.spec.actuator_names], dtype=float)

    def reading_from_physical(self, physical_rad: np.ndarray) -> np.ndarray:
        """What the servos read (before quantisation and noise) at physical angles (n_act,)."""
        return np.asarray(physical_rad, dtype=float) - self.offsets_rad()

    def physical_from_reading(self, reading_rad: np.ndarray) -> np.ndarray:
        return np.asarray(reading_rad, dtype=float) + self.offsets_rad()

    def check_against(self, spec: ArmSpec) -> None:
        """The user's spec must describe the same actuators, in the same order, on the same ids:
        otherwise a command for one joint would drive another."""
        if spec.actuator_names != self.spec.actuator_names:
            raise SpecError(
                f"{self.source}: plant actuators {list(self.spec.actuator_names)} do not match "
                f"spec {spec.name!r} actuators {list(spec.actuator_names)}"
            )
        if spec.actuator_ids != self.spec.actuator_ids:
            raise SpecError(
                f"{self.source}: plant servo ids {list(self.spec.actuator_ids)} do not match "
                f"spec {spec.name!r} servo ids {list(spec.actuator_ids)}"
            )
        axes = [j.axis for j in self.spec.joints]
        if [j.axis for j in spec.joints] != axes:
            raise SpecError(
                f"{self.source}: plant joint axes {axes} do not match spec {spec.name!r} axes "
                f"{[j.axis for j in spec.joints]}"
            )

    # ---- the emulator -----------------------------------------------------------------------
    def emulator_config(self, config: EmulatorConfig | None = None) -> EmulatorConfig:
        """``config`` (wire timing, faults, seed...) with the plant's droop, noise and command
        latency: those are the truth, so they replace whatever ``config`` said."""
        from hardware.emulator.server import EmulatorConfig

        base = config or EmulatorConfig()
        return replace(
            base,
            droop_rad=self.droop_rad,
            noise_rad=self.noise_rad,
            command_latency_s=self.command_latency_s,
        )

    def mounting(self, protocol: str) -> ArmCalibration:
        """The emulator's true mounting: the nominal servo mapping with each horn turned by its
        offset. A host on the nominal calibration then reads ``physical - offset``."""
        from hardware.joint_calibration import nominal_calibration, with_joints
        from hardware.protocols import get_protocol

        frame = get_protocol(protocol).unit_frame(self.spec)
        base = nominal_calibration(self.spec, protocol, frame, arm_id="plant")
        # units = offset_u + dir * scale * physical, and the host decodes
        # (units - centre) / scale = reading, so offset_u = centre - dir * scale * offset
        shifted = base.offset_units - base.direction * base.scale_units_per_rad * self.offsets_rad()
        return with_joints(base, offsets_units=[float(v) for v in shifted])

    def emulator(
        self,
        protocol: str = "s2r",
        config: EmulatorConfig | None = None,
        link: str | os.PathLike[str] | None = None,
    ) -> Emulator:
        """An (unstarted) emulator that behaves as this plant: servo figures from
        ``self.spec``, defects from the ``plant:`` mapping, offsets in its mounting."""
        from hardware.emulator.server import Emulator

        return Emulator(
            self.spec,
            protocol,
            self.emulator_config(config),
            mounting=self.mounting(protocol),
            link=link,
        )

    # ---- io ---------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        out = self.spec.to_dict()
        defects: dict[str, Any] = {}
        if self.joint_offset_rad:  # yamlio writes an empty mapping as '{}', which it cannot read
            defects["joint_offset_rad"] = {n: float(v) for n, v in self.joint_offset_rad}
        defects.update(
            command_latency_s=float(self.command_latency_s),
            droop_rad=float(self.droop_rad),
            noise_rad=float(self.noise_rad),
        )
        out[PLANT_KEY] = defects
        return out

    @classmethod
    def from_dict(cls, data: Any, source: str = "plant") -> Plant:
        """Build and validate; every error is one line naming ``source``, the key and value."""
        if not isinstance(data, dict):
            raise SpecError(
                f"{source}: expected a mapping at the top level, got {type(data).__name__}"
            )
        body = {k: v for k, v in data.items() if k != PLANT_KEY}
        spec = ArmSpec.from_dict(body, source=source)
        raw = data.get(PLANT_KEY) or {}
        if not isinstance(raw, dict):
            raise SpecError(f"{source}: {PLANT_KEY} must be a mapping, got {raw!r}")
        unknown = sorted(set(raw) - set(_DEFECT_KEYS))
        if unknown:
            raise SpecError(
                f"{source}: unknown {PLANT_KEY} key(s) {unknown}; valid: {sorted(_DEFECT_KEYS)}"
            )
        offsets_raw = raw.get("joint_offset_rad") or {}
        if not isinstance(offsets_raw, dict):
            raise SpecError(
                f"{source}: plant.joint_offset_rad must map joint names to rad, got {offsets_raw!r}"
            )
        offsets = tuple(
            (str(name), _number(source, f"plant.joint_offset_rad.{name}", v, non_negative=False))
            for name, v in offsets_raw.items()
        )
        values = {
            key: _number(source, f"plant.{key}", raw.get(key, 0.0), non_negative=True)
            for key in ("command_latency_s", "droop_rad", "noise_rad")
        }
        return cls(spec=spec, joint_offset_rad=offsets, source=source, **values)

    def to_yaml(self, path: str | os.PathLike[str], header: str = "") -> None:
        """Written atomically (yamlio.dump goes through hardware.atomic)."""
        yamlio.dump(path, self.to_dict(), header=header or f"Plant {self.spec.name}")


def plant_names() -> list[str]:
    return sorted(p.stem for p in PLANT_DIR.glob("*.yaml"))


def load_plant(path: str | os.PathLike[str]) -> Plant:
    """A plant file, or a shipped preset by name (``mild``, ``moderate``, ``hard``)."""
    text = os.fspath(path)
    p = Path(text)
    if not p.is_file() and not text.endswith((".yaml", ".yml")) and os.sep not in text:
        preset = PLANT_DIR / f"{text}.yaml"
        if not preset.is_file():
            raise SpecError(
                f"plant {text!r} is neither a file nor a preset; presets: {plant_names()}"
            )
        p = preset
    if not p.is_file():
        raise SpecError(f"plant file {text!r} does not exist")
    return Plant.from_dict(yamlio.load(p), source=str(p))
