"""Actuation DR: samples the servo's parameters per episode (units in the names; ranges in
``presets/*.yaml``). The servo they configure is ``sim2real.actuation.ServoActuation`` (the one
servo model, ``hardware.servo_model``): DR samples parameters, it does not own the model.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from sim2real.actuation import ServoActuation
from sim2real.randomization.base import DirectKey, ModelIds, Params, draw_keys, round_steps
from sim2real.randomization.config import Range

__all__ = [
    "ServoActuation",
    "direct_keys",
    "sample",
]  # ServoActuation: for importers not yet moved (envs/base)


def sample(rng: np.random.Generator, ranges: Mapping[str, Range], ids: ModelIds) -> Params:
    """The servo's parameters for one episode (``direct_keys``)."""
    return draw_keys(direct_keys(ids), rng, ranges)


def direct_keys(ids: ModelIds) -> list[DirectKey]:
    """The servo's draws, in their order."""
    return [
        ("latency_steps", None, round_steps),
        ("action_noise_rad", None, float),
        ("max_speed_scale", None, float),
        ("deadband_rad", None, float),
        ("quantisation_rad", None, float),
    ]
