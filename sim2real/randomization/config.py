"""DR presets: named YAML files of ranges with units, validated on load."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sim2real.errors import ConfigError, UnknownNameError

PRESET_DIR = Path(__file__).with_name("presets")

# Category → key → neutral range (no randomisation). A preset may omit any key; unknown keys fail.
NEUTRAL: dict[str, dict[str, tuple[float, float]]] = {
    "dynamics": {
        "link_mass_scale": (1.0, 1.0),
        "joint_damping_scale": (1.0, 1.0),
        "joint_frictionloss_nm": (0.0, 0.0),
        "armature_scale": (1.0, 1.0),
        "actuator_gain_scale": (1.0, 1.0),
        "actuator_droop_rad": (0.0, 0.0),
    },
    "actuation": {
        "latency_steps": (0.0, 0.0),
        "action_noise_rad": (0.0, 0.0),
        "max_speed_scale": (1.0, 1.0),
        "deadband_rad": (0.0, 0.0),
        "quantisation_rad": (0.0, 0.0),
    },
    "sensing": {
        "joint_noise_rad": (0.0, 0.0),
        "joint_bias_rad": (0.0, 0.0),
        "stereo_pixel_noise_px": (0.0, 0.0),
        "position_bias_m": (0.0, 0.0),
        "obs_delay_steps": (0.0, 0.0),
        "point_dropout_prob": (0.0, 0.0),
        "occlusion_radius_m": (0.0, 0.0),
        "occlusion_prob": (0.0, 0.0),
    },
    "visual": {
        "light_diffuse_scale": (1.0, 1.0),
        "light_pos_jitter_m": (0.0, 0.0),
        "rgba_jitter": (0.0, 0.0),
        "camera_pos_jitter_m": (0.0, 0.0),
        "camera_fovy_jitter_deg": (0.0, 0.0),
    },
    "object": {
        "size_scale": (1.0, 1.0),
        "mass_scale": (1.0, 1.0),
        "friction": (1.2, 1.2),
        "init_xy_jitter_m": (0.0, 0.0),
    },
    "kinematics": {
        "link_length_delta_m": (0.0, 0.0),
        "joint_offset_rad": (0.0, 0.0),
        "tool_offset_delta_m": (0.0, 0.0),
    },
}
CATEGORY_NAMES: tuple[str, ...] = tuple(NEUTRAL)
_NON_NEGATIVE_SUFFIXES = (
    "_scale",
    "_steps",
    "noise_rad",
    "noise_px",
    "_jitter_m",
    "deadband_rad",
    "droop_rad",
    "_prob",
    "radius_m",
)


@dataclass(frozen=True)
class Range:
    """A uniform range [low, high] in the unit its key names."""

    low: float
    high: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.low) and math.isfinite(self.high)):
            raise ConfigError(f"range [{self.low}, {self.high}] must be finite")
        if self.low > self.high:
            raise ConfigError(f"range [{self.low}, {self.high}] has low > high")

    def sample(self, rng: np.random.Generator, size: int | None = None) -> Any:
        if self.low == self.high:
            return self.low if size is None else np.full(size, self.low)
        return rng.uniform(self.low, self.high, size)

    @property
    def is_neutral_point(self) -> bool:
        return self.low == self.high


@dataclass(frozen=True)
class DRConfig:
    """A full preset: category → key → Range, with every key filled (omitted = neutral)."""

    name: str
    ranges: Mapping[str, Mapping[str, Range]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        filled: dict[str, dict[str, Range]] = {}
        for cat, neutral in NEUTRAL.items():
            given = dict(self.ranges.get(cat, {}))
            unknown = sorted(set(given) - set(neutral))
            if unknown:
                raise ConfigError(
                    f"DR preset {self.name!r}: unknown {cat} key(s) {unknown}; "
                    f"valid: {sorted(neutral)}"
                )
            filled[cat] = {k: given.get(k, Range(*v)) for k, v in neutral.items()}
            for key, rng in filled[cat].items():
                if key.endswith(_NON_NEGATIVE_SUFFIXES) and rng.low < 0:
                    raise ConfigError(
                        f"DR preset {self.name!r}: {cat}.{key} low {rng.low} must be >= 0"
                    )
                if key.endswith("_prob") and rng.high > 1.0:
                    raise ConfigError(
                        f"DR preset {self.name!r}: {cat}.{key} high {rng.high} must be <= 1 "
                        "(a probability)"
                    )
        unknown_cats = sorted(set(self.ranges) - set(NEUTRAL))
        if unknown_cats:
            raise ConfigError(
                f"DR preset {self.name!r}: unknown categories {unknown_cats}; "
                f"valid: {list(NEUTRAL)}"
            )
        object.__setattr__(self, "ranges", filled)

    def __getitem__(self, category: str) -> Mapping[str, Range]:
        return self.ranges[category]

    def is_neutral(self, category: str) -> bool:
        return all(
            r.low == NEUTRAL[category][k][0] and r.high == NEUTRAL[category][k][1]
            for k, r in self.ranges[category].items()
        )

    def to_dict(self) -> dict[str, dict[str, list[float]]]:
        return {
            cat: {k: [r.low, r.high] for k, r in keys.items()} for cat, keys in self.ranges.items()
        }

    @classmethod
    def from_dict(cls, name: str, data: Any) -> DRConfig:
        if not isinstance(data, dict):
            raise ConfigError(f"DR preset {name!r}: expected a mapping, got {data!r}")
        ranges: dict[str, dict[str, Range]] = {}
        for cat, keys in data.items():
            keys = keys or {}
            if not isinstance(keys, dict):
                raise ConfigError(f"DR preset {name!r}: {cat} must be a mapping, got {keys!r}")
            ranges[cat] = {}
            for key, value in keys.items():
                if not (isinstance(value, list) and len(value) == 2):
                    raise ConfigError(
                        f"DR preset {name!r}: {cat}.{key} must be [low, high], got {value!r}"
                    )
                try:
                    low, high = float(value[0]), float(value[1])
                except (TypeError, ValueError):
                    raise ConfigError(
                        f"DR preset {name!r}: {cat}.{key} must be numbers, got {value!r}"
                    ) from None
                try:
                    ranges[cat][key] = Range(low, high)
                except ConfigError as exc:
                    raise ConfigError(f"DR preset {name!r}: {cat}.{key}: {exc}") from None
        return cls(name=name, ranges=ranges)


def preset_names() -> list[str]:
    return sorted(p.stem for p in PRESET_DIR.glob("*.yaml"))


def load_preset(name_or_path: str | Path | DRConfig) -> DRConfig:
    """A shipped preset by name, or a YAML file by path."""
    if isinstance(name_or_path, DRConfig):
        return name_or_path
    text = str(name_or_path)
    path = Path(text)
    if not (text.endswith((".yaml", ".yml")) or path.is_file()):
        path = PRESET_DIR / f"{text}.yaml"
        if not path.is_file():
            raise UnknownNameError("DR preset", text, preset_names())
    elif not path.is_file():
        raise ConfigError(f"DR preset file {text!r} does not exist")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"DR preset {text!r} is not valid YAML: {exc}".splitlines()[0]) from None
    return DRConfig.from_dict(path.stem, data)
