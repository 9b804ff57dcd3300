"""What each stage of ``sim2real adapt`` found, as typed values.

The stages return these; JSON is made only where it is printed or kept (``to_json``: the CLI's
lines, ``status.json``, ``zero_shot.json`` and ``evaluate.json``), in the format adapt has always
written: the same keys, in the same order, with the same values. ``StageResult.from_json`` reads
a finished stage back from ``status.json`` when a run continues.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol


class StageFigures(Protocol):
    def to_json(self) -> dict[str, Any]: ...


def _pair(value: Any) -> tuple[float, float]:
    """Two numbers as written (not converted: the JSON read back is the JSON written)."""
    lo, hi = value
    return lo, hi


def _strings(value: Any) -> tuple[str, ...]:
    return tuple(str(v) for v in value)


@dataclass(frozen=True)
class DeployFigures:
    """A deploy stage (``zero_shot``): the policy's episodes on the arm."""

    episodes: int
    successes: int
    success_rate: float
    success_wilson95: tuple[float, float]
    mean_final_distance_m: float  # NaN: no episode ended with a finite distance
    watchdog_trips: int

    def __post_init__(self) -> None:
        if not 0 <= self.successes <= self.episodes:
            raise ValueError(f"deploy figures: {self.successes} successes in {self.episodes}")

    def to_json(self) -> dict[str, Any]:
        return {
            "episodes": self.episodes,
            "successes": self.successes,
            "success_rate": self.success_rate,
            "success_wilson95": list(self.success_wilson95),
            "mean_final_distance_m": self.mean_final_distance_m,
            "watchdog_trips": self.watchdog_trips,
        }

    @classmethod
    def _fields_from(cls, d: Mapping[str, Any]) -> dict[str, Any]:
        return {
            "episodes": int(d["episodes"]),
            "successes": int(d["successes"]),
            "success_rate": float(d["success_rate"]),
            "success_wilson95": _pair(d["success_wilson95"]),
            "mean_final_distance_m": float(d["mean_final_distance_m"]),
            "watchdog_trips": int(d["watchdog_trips"]),
        }

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> DeployFigures:
        return cls(**cls._fields_from(d))


@dataclass(frozen=True)
class EvaluateFigures(DeployFigures):
    """The adapted policy's deploy (``evaluate``), beside the zero-shot cell it is compared to."""

    zero_shot_success_rate: float | None = None  # None: no zero-shot stage to compare
    zero_shot_wilson95: tuple[float, float] | None = None

    def to_json(self) -> dict[str, Any]:
        zero = self.zero_shot_wilson95
        return {
            **super().to_json(),
            "zero_shot_success_rate": self.zero_shot_success_rate,
            "zero_shot_wilson95": None if zero is None else list(zero),
        }

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> EvaluateFigures:
        zero = d.get("zero_shot_wilson95")
        rate = d.get("zero_shot_success_rate")
        return cls(
            **cls._fields_from(d),
            zero_shot_success_rate=None if rate is None else float(rate),
            zero_shot_wilson95=None if zero is None else _pair(zero),
        )


@dataclass(frozen=True)
class RecordFigures:
    """The excitations recorded on the arm (``record``)."""

    servo_periods: int
    kinematic_periods: int
    kinematic_s: float
    marker_seen_rate: float  # the fraction of kinematic periods with the wrist marker seen
    logs: tuple[str, ...]  # relative to the adapt folder

    SERVO_LOG: ClassVar[str] = "record/servo.npz"
    KINEMATIC_LOG: ClassVar[str] = "record/kinematics.npz"

    def __post_init__(self) -> None:
        if not 0.0 <= self.marker_seen_rate <= 1.0:
            raise ValueError(f"record figures: marker seen rate {self.marker_seen_rate}")

    def log_names(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """The servo logs and the kinematic logs, relative to the adapt folder."""
        return (self.SERVO_LOG,), (self.KINEMATIC_LOG,)

    def to_json(self) -> dict[str, Any]:
        return {
            "servo_periods": self.servo_periods,
            "kinematic_periods": self.kinematic_periods,
            "kinematic_s": self.kinematic_s,
            "marker_seen_rate": self.marker_seen_rate,
            "logs": list(self.logs),
        }

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> RecordFigures:
        return cls(
            servo_periods=int(d["servo_periods"]),
            kinematic_periods=int(d["kinematic_periods"]),
            kinematic_s=d["kinematic_s"],
            marker_seen_rate=float(d["marker_seen_rate"]),
            logs=_strings(d["logs"]),
        )


@dataclass(frozen=True)
class GivenLogsFigures:
    """The given ``--logs`` (``record`` without the arm): where their copies are, and whence."""

    servo_logs: tuple[str, ...]  # copies, relative to the adapt folder
    kinematic_logs: tuple[str, ...]
    given: tuple[str, ...]  # the paths as given

    def log_names(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        return self.servo_logs, self.kinematic_logs

    def to_json(self) -> dict[str, Any]:
        return {
            "logs": {"servo": list(self.servo_logs), "kinematics": list(self.kinematic_logs)},
            "given": list(self.given),
        }

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> GivenLogsFigures:
        logs = d["logs"]
        return cls(_strings(logs["servo"]), _strings(logs["kinematics"]), _strings(d["given"]))


@dataclass(frozen=True)
class SysidFigures:
    """The servo fit and the kinematic fit (``sysid``), rounded as reported; the full fit with
    its covariance is in ``sysid.json``."""

    servo: Mapping[str, float]  # ``ServoFit``'s fields, by name
    servo_rms_rad: float
    kinematics: Mapping[str, float]  # ``KinematicFit.as_dict()``: values, 1-sigma, residual

    def __post_init__(self) -> None:
        if "servo_rms_rad" in self.servo or set(self.servo) & set(self.kinematics):
            raise ValueError(f"sysid figures: names overlap: {sorted(self.servo)}")

    def to_json(self) -> dict[str, Any]:
        return {**self.servo, "servo_rms_rad": self.servo_rms_rad, **self.kinematics}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> SysidFigures:
        """The servo's names come before ``servo_rms_rad``, the kinematic ones after it (the
        order ``to_json`` wrote them in)."""
        names = list(d)
        split = names.index("servo_rms_rad")
        return cls(
            servo={k: d[k] for k in names[:split]},
            servo_rms_rad=float(d["servo_rms_rad"]),
            kinematics={k: d[k] for k in names[split + 1 :]},
        )


@dataclass(frozen=True)
class FitFigures:
    """The fitted spec, the DR preset centred on it and the joint calibration (``fit``)."""

    spec: str  # file names, relative to the adapt folder
    dr_preset: str
    joint_calibration: str
    fingerprint: str  # the fitted spec's
    link_change_mm: tuple[float, ...]  # base height, upper arm, forearm: fitted - nominal
    joint_offset_rad: tuple[float, ...]
    dr_link_half_width_m: float
    dr_offset_half_width_rad: float
    dr_latency_steps: tuple[float, float]  # the preset's range, in control steps

    def to_json(self) -> dict[str, Any]:
        return {
            "spec": self.spec,
            "dr_preset": self.dr_preset,
            "joint_calibration": self.joint_calibration,
            "fingerprint": self.fingerprint,
            "link_change_mm": list(self.link_change_mm),
            "joint_offset_rad": list(self.joint_offset_rad),
            "dr_link_half_width_m": self.dr_link_half_width_m,
            "dr_offset_half_width_rad": self.dr_offset_half_width_rad,
            "dr_latency_steps": list(self.dr_latency_steps),
        }

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> FitFigures:
        return cls(
            spec=str(d["spec"]),
            dr_preset=str(d["dr_preset"]),
            joint_calibration=str(d["joint_calibration"]),
            fingerprint=str(d["fingerprint"]),
            link_change_mm=tuple(d["link_change_mm"]),
            joint_offset_rad=tuple(d["joint_offset_rad"]),
            dr_link_half_width_m=d["dr_link_half_width_m"],
            dr_offset_half_width_rad=d["dr_offset_half_width_rad"],
            dr_latency_steps=_pair(d["dr_latency_steps"]),
        )


@dataclass(frozen=True)
class FinetuneFigures:
    """The fine-tune in sim under the fitted spec (``finetune``)."""

    run_dir: str  # relative to the adapt folder
    steps: int  # env steps this adaptation trained (not the source's)
    wall_s: float
    budget_s: float
    steps_per_s: float | None  # None: nothing left to train this run
    train_success_rate: float | None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.budget_s) and self.budget_s > 0):
            raise ValueError(f"finetune figures: budget {self.budget_s} s")

    def to_json(self) -> dict[str, Any]:
        return {
            "run_dir": self.run_dir,
            "steps": self.steps,
            "wall_s": self.wall_s,
            "budget_s": self.budget_s,
            "steps_per_s": self.steps_per_s,
            "train_success_rate": self.train_success_rate,
        }

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> FinetuneFigures:
        return cls(
            run_dir=str(d["run_dir"]),
            steps=int(d["steps"]),
            wall_s=d["wall_s"],
            budget_s=d["budget_s"],
            steps_per_s=d["steps_per_s"],
            train_success_rate=d["train_success_rate"],
        )


@dataclass(frozen=True)
class ExportFigures:
    """The exported ONNX policy (``export``)."""

    policy: str  # relative to the adapt folder
    size_bytes: int
    fingerprint: str  # the fitted spec's, which the policy carries

    def to_json(self) -> dict[str, Any]:
        return {"policy": self.policy, "bytes": self.size_bytes, "fingerprint": self.fingerprint}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> ExportFigures:
        return cls(str(d["policy"]), int(d["bytes"]), str(d["fingerprint"]))


def _record_from_json(d: Mapping[str, Any]) -> StageFigures:
    """Recorded on the arm (``logs``: a list) or given (``logs``: servo and kinematic lists)."""
    if isinstance(d["logs"], Mapping):
        return GivenLogsFigures.from_json(d)
    return RecordFigures.from_json(d)


_READERS: dict[str, Any] = {
    "zero_shot": DeployFigures.from_json,
    "record": _record_from_json,
    "sysid": SysidFigures.from_json,
    "fit": FitFigures.from_json,
    "finetune": FinetuneFigures.from_json,
    "export": ExportFigures.from_json,
    "evaluate": EvaluateFigures.from_json,
}


@dataclass(frozen=True)
class StageResult:
    """One stage's figures and its wall time; ``resumed``: finished by an earlier run."""

    stage: str
    figures: StageFigures
    stage_wall_s: float
    resumed: bool = False

    def __post_init__(self) -> None:
        if self.stage not in _READERS:
            raise ValueError(f"unknown adapt stage {self.stage!r}")

    def to_json(self) -> dict[str, Any]:
        """The stage's figures as the CLI prints them; ``status.json`` keeps them without
        ``resumed``."""
        out = {**self.figures.to_json(), "stage_wall_s": self.stage_wall_s}
        if self.resumed:
            out["resumed"] = True
        return out

    @classmethod
    def from_json(cls, stage: str, d: Mapping[str, Any], resumed: bool = True) -> StageResult:
        """A finished stage read back from ``status.json``. Raises KeyError, TypeError or
        ValueError on figures of another shape."""
        if stage not in _READERS:
            raise ValueError(f"unknown adapt stage {stage!r}")
        figures = _READERS[stage]({k: v for k, v in d.items() if k != "stage_wall_s"})
        return cls(stage, figures, float(d["stage_wall_s"]), resumed)
