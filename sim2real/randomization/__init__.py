"""Domain randomisation in six categories, each a pure (sample, apply) pair with exact restore.

``dynamics``, ``visual``, ``object`` and ``kinematics`` write the MjModel from its nominal
snapshot; ``actuation``
and ``sensing`` configure the servo and sensor layers the env runs every step. Presets are YAML
files of unit-named ranges (``presets/``), chosen with ``gym.make(id, dr="default")``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from sim2real.errors import ConfigError
from sim2real.randomization import actuation, dynamics, kinematics, sensing, visual
from sim2real.randomization import object as object_dr
from sim2real.randomization.base import ModelIds, ModelSnapshot, Params
from sim2real.randomization.config import (
    CATEGORY_NAMES,
    DRConfig,
    Range,
    load_preset,
    preset_names,
)
from sim2real.randomization.replay import DrawPlan

Sampler = Callable[[np.random.Generator, Mapping[str, Range], ModelIds], Params]
Applier = Callable[[mujoco.MjModel, ModelSnapshot, ModelIds, Params], None]


@dataclass(frozen=True)
class Category:
    """One DR category: ``apply`` is None for layers that act at run time, not on the model."""

    sample: Sampler
    apply: Applier | None


CATEGORIES: dict[str, Category] = {
    "dynamics": Category(dynamics.sample, dynamics.apply),
    "actuation": Category(actuation.sample, None),
    "sensing": Category(sensing.sample, None),
    "visual": Category(visual.sample, visual.apply),
    "object": Category(object_dr.sample, object_dr.apply),
    # last, so adding it left every other category's draws (and old seeds' episodes) as they were
    "kinematics": Category(kinematics.sample, kinematics.apply),
}
assert tuple(CATEGORIES) == CATEGORY_NAMES


class DomainRandomizer:
    """Samples a preset per episode and writes it into the model; restores nominal exactly."""

    def __init__(self, model: mujoco.MjModel, ids: ModelIds, config: DRConfig) -> None:
        self.model = model
        self.ids = ids
        self.config = config
        self.nominal = ModelSnapshot(model)
        # Worked out once: the config is frozen, so which categories write the model is fixed.
        self._appliers = [
            (name, cat.apply)
            for name, cat in CATEGORIES.items()
            if cat.apply is not None and not config.is_neutral(name)
        ]
        self._ranges = [(name, cat.sample, config[name]) for name, cat in CATEGORIES.items()]
        try:
            self._plan: DrawPlan | None = DrawPlan.record(self._sample_with)
        except (AttributeError, TypeError, ConfigError):  # a draw the replay does not offer
            self._plan = None

    def _sample_with(self, rng: Any) -> dict[str, Params]:
        return {name: sample(rng, ranges, self.ids) for name, sample, ranges in self._ranges}

    def sample(self, rng: np.random.Generator) -> dict[str, Params]:
        """Draw every category in a fixed order so a seed fixes the whole episode: the same
        values and generator state as ``sample_reference``, in a few RNG calls (``replay``)."""
        if self._plan is None:
            return self._sample_with(rng)
        replay = self._plan.replayer(rng)
        params = self._sample_with(replay)
        replay.done()
        return params

    def sample_reference(self, rng: np.random.Generator) -> dict[str, Params]:
        """Every category drawn straight from ``rng``: what ``sample`` is held to."""
        return self._sample_with(rng)

    def apply(self, params: Mapping[str, Params]) -> None:
        self.nominal.restore()
        for name, apply in self._appliers:
            apply(self.model, self.nominal, self.ids, params[name])

    def restore_nominal(self) -> None:
        self.nominal.restore()


__all__ = [
    "CATEGORIES",
    "DRConfig",
    "DomainRandomizer",
    "ModelIds",
    "ModelSnapshot",
    "Range",
    "load_preset",
    "preset_names",
]
