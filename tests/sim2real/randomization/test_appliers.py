"""Each applier that writes through a per-model plan against its reference (the straight
per-field version): the same model bytes after every episode, on the arm scenes and presets."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np
import pytest

import sim2real.envs  # noqa: F401
from sim2real.randomization import DomainRandomizer, DRConfig, dynamics, kinematics, visual
from sim2real.randomization.base import TOUCHED_FIELDS
from sim2real.randomization.config import Range

PAIRS: dict[str, tuple[Callable[..., None], Callable[..., None]]] = {
    "dynamics": (dynamics.apply, dynamics.apply_reference),
    "visual": (visual.apply, visual.apply_reference),
    "kinematics": (kinematics.apply, kinematics.apply_reference),
}


# the shipped presets have no droop: this one writes the bias term with the gain it scales
SAGGING = DRConfig(
    "sagging",
    {
        "dynamics": {
            "actuator_gain_scale": Range(0.7, 1.3),
            "actuator_droop_rad": Range(0.0, 0.03),
        }
    },
)


def _randomizer(env_id: str, preset: str | DRConfig) -> DomainRandomizer:
    return gym.make(env_id, dr=preset).unwrapped.randomizer  # type: ignore[no-any-return]


CASES = [
    pytest.param(preset, category, id=f"{preset}-{category}")
    for preset in ("default", "strong")
    for category in PAIRS
] + [pytest.param(SAGGING, "dynamics", id="sagging-dynamics")]


@pytest.mark.parametrize("env_id", ["Sim2Real/Arm3Reach-v0", "Sim2Real/Arm3Pick-v0"])
@pytest.mark.parametrize(("preset", "category"), CASES)
def test_planned_apply_writes_the_reference_bytes(
    env_id: str, preset: str | DRConfig, category: str
) -> None:
    fast, ref = _randomizer(env_id, preset), _randomizer(env_id, preset)
    apply, apply_reference = PAIRS[category]
    rng = np.random.default_rng(7)
    changed = 0
    for _ in range(25):
        params = fast.sample_reference(rng)[category]
        fast.nominal.restore()
        ref.nominal.restore()
        apply(fast.model, fast.nominal, fast.ids, params)
        apply_reference(ref.model, ref.nominal, ref.ids, params)
        for field in TOUCHED_FIELDS:
            a, b = getattr(fast.model, field), getattr(ref.model, field)
            assert a.tobytes() == b.tobytes(), field
            changed += a.tobytes() != fast.nominal[field].tobytes()
    assert changed > 0  # the category did write something


def test_the_plan_follows_a_new_model() -> None:
    """Plans are per model: a second env's randomizer writes its own model, not the first's."""
    first, second = _randomizer("Sim2Real/Arm3Reach-v0", "strong"), None
    rng = np.random.default_rng(1)
    first.apply(first.sample(rng))
    second = _randomizer("Sim2Real/Arm3Reach-v0", "strong")
    before = first.model.body_quat.copy()
    second.apply(second.sample(rng))
    assert first.model.body_quat.tobytes() == before.tobytes()
    assert second.model.body_quat.tobytes() != second.nominal["body_quat"].tobytes()


def test_colour_dr_jitters_the_colour_a_textured_geom_is_drawn_in() -> None:
    """The table is drawn in its (white, textured) material's colour while its own rgba is
    MuJoCo's default; colour DR must stay near that colour, not replace it by the default grey."""
    from sim2real import model as names

    env = gym.make("Sim2Real/Arm3ReachPixels-v0", dr="default", image_size=48)
    try:
        m = env.unwrapped.model  # type: ignore[attr-defined]
        table = m.geom(names.TABLE_GEOM).id
        material = m.mat_rgba[m.geom_matid[table]].copy()
        drawn = []
        for seed in range(8):
            env.reset(seed=seed)
            rgba = m.geom_rgba[table]
            drawn.append(rgba.copy())
        drawn_rgb = np.array(drawn)[:, :3]
        # within the preset's 0.15 colour jitter of the material's colour on every draw
        assert np.all(np.abs(drawn_rgb - material[:3]) <= 0.15 + 1e-6)
        assert not np.allclose(drawn_rgb, material[:3])  # and it does jitter
    finally:
        env.close()
