"""Domain randomisation in six categories, each a pure (sample, apply) pair with exact restore.

``dynamics``, ``visual``, ``object`` and ``kinematics`` write the MjModel from its nominal
snapshot; ``actuation``
and ``sensing`` configure the servo and sensor layers the env runs every step. Presets are YAML
files of unit-named ranges (``presets/``), chosen with ``gym.make(id, dr="default")``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import mujoco
import numpy as np

from sim2real.errors import ConfigError
from sim2real.randomization import actuation, dynamics, kinematics, sensing, visual
from sim2real.randomization import object as object_dr
from sim2real.randomization.base import DirectKey, ModelIds, ModelSnapshot, Params
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


# (key, size, cast): a category whose parameters are each one ``Range.sample(rng, size)`` in
# this order, cast (``float``, ``round``) or not, lists them so a reset can take them straight
# from the replayed draws (``tests/sim2real/randomization/test_replay.py`` holds them to
# ``sample``).
DirectKeys = Callable[[ModelIds], Sequence[DirectKey]]
# per key: (key, recorded call or -1 when neutral, the neutral value, size, cast)
_Direct = list[tuple[str, int, Any, int | None, Callable[[Any], Any] | None]]


@dataclass(frozen=True)
class Category:
    """One DR category: ``apply`` is None for layers that act at run time, not on the model."""

    sample: Sampler
    apply: Applier | None
    direct: DirectKeys | None = None


def _draw(sample: Sampler, rng: Any, ranges: Mapping[str, Range], ids: ModelIds) -> Params:
    return sample(rng, ranges, ids)


def _direct_plan(
    cat: Category, ranges: Mapping[str, Range], ids: ModelIds, plan: DrawPlan, span: list[int]
) -> _Direct | None:
    """Match a listing category's keys to its recorded calls; None when it does not list them
    or they do not match (the sampler then runs on the replay, checked call by call)."""
    if cat.direct is None:
        return None
    out: _Direct = []
    call = span[0]
    for key, size, cast in cat.direct(ids):
        r = ranges[key]
        if r.low == r.high:
            out.append((key, -1, r.low, size, cast))
            continue
        if call >= span[1] or plan.calls[call] != ("u", size, float(r.low), float(r.high)):
            return None
        out.append((key, call, None, size, cast))
        call += 1
    return out if call == span[1] else None


CATEGORIES: dict[str, Category] = {
    "dynamics": Category(dynamics.sample, dynamics.apply, dynamics.direct_keys),
    "actuation": Category(actuation.sample, None, actuation.direct_keys),
    "sensing": Category(sensing.sample, None, sensing.direct_keys),
    "visual": Category(visual.sample, visual.apply),
    "object": Category(object_dr.sample, object_dr.apply),
    # last, so adding it left every other category's draws (and old seeds' episodes) as they were
    "kinematics": Category(kinematics.sample, kinematics.apply, kinematics.direct_keys),
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
        self._plan: DrawPlan | None = None
        # per category: its sampler's first recorded call, and for a category that lists its
        # draws (``Category.direct``) the recorded call behind each key
        self._steps: list[tuple[str, Sampler, Mapping[str, Range], int, int, _Direct | None]]
        self._steps = []
        try:
            self._plan, starts = DrawPlan.record(
                [partial(_draw, sample, ranges=r, ids=ids) for _, sample, r in self._ranges]
            )
        except (AttributeError, TypeError, ConfigError):  # a draw the replay does not offer
            return
        for k, (name, sample, ranges) in enumerate(self._ranges):
            direct = _direct_plan(CATEGORIES[name], ranges, ids, self._plan, starts[k : k + 2])
            self._steps.append((name, sample, ranges, starts[k], starts[k + 1], direct))

    def _sample_with(self, rng: Any) -> dict[str, Params]:
        return {name: sample(rng, ranges, self.ids) for name, sample, ranges in self._ranges}

    def sample(self, rng: np.random.Generator) -> dict[str, Params]:
        """Draw every category in a fixed order so a seed fixes the whole episode: the same
        values and generator state as ``sample_reference``, in a few RNG calls (``replay``)."""
        if self._plan is None:
            return self._sample_with(rng)
        replay = self._plan.replayer(rng)
        params: dict[str, Params] = {}
        for name, sample, ranges, start, end, direct in self._steps:
            if direct is None:
                replay.seek(start)
                params[name] = sample(replay, ranges, self.ids)  # type: ignore[arg-type]
                if replay.at != end:
                    raise RuntimeError(f"DR category {name!r} drew off its recording")
                continue
            out: Params = {}
            for key, call, const, size, cast in direct:
                if call < 0:  # a neutral key: no draw, its point value
                    value = const if size is None else np.full(size, const)
                else:
                    value = replay.value(call)
                out[key] = value if cast is None else cast(value)
            params[name] = out
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
