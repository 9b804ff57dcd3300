"""Actuation DR: samples the servo's parameters per episode (units in the names; ranges in
``presets/*.yaml``). The servo they configure is ``sim2real.actuation.ServoActuation`` (the one
servo model, ``hardware.servo_model``): DR samples parameters, it does not own the model.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from sim2real.actuation import ServoActuation
from sim2real.randomization.base import ModelIds, Params
from sim2real.randomization.config import Range

__all__ = [
    "ServoActuation",
    "direct_keys",
    "sample",
]  # ServoActuation: for importers not yet moved (envs/base)


def sample(rng: np.random.Generator, ranges: Mapping[str, Range], ids: ModelIds) -> Params:
    return {
        "latency_steps": round(float(ranges["latency_steps"].sample(rng))),
        "action_noise_rad": float(ranges["action_noise_rad"].sample(rng)),
        "max_speed_scale": float(ranges["max_speed_scale"].sample(rng)),
        "deadband_rad": float(ranges["deadband_rad"].sample(rng)),
        "quantisation_rad": float(ranges["quantisation_rad"].sample(rng)),
    }


def _steps(x: Any) -> int:
    return round(float(x))


def direct_keys(ids: ModelIds) -> list[tuple[str, int | None, Callable[[Any], Any]]]:
    """``sample``'s keys in its order, each one scalar ``Range.sample`` cast as there."""
    return [
        ("latency_steps", None, _steps),
        ("action_noise_rad", None, float),
        ("max_speed_scale", None, float),
        ("deadband_rad", None, float),
        ("quantisation_rad", None, float),
    ]
