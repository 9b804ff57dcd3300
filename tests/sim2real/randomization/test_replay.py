"""The replayed DR draws (``randomization.replay``) against the samplers drawing straight from
the generator: the same values, types and shapes, and the generator left in the same state."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import sim2real.envs  # noqa: F401
from sim2real.randomization import CATEGORIES, DomainRandomizer, DRConfig, Range, preset_names
from sim2real.randomization.replay import DrawPlan


def _assert_same(a: Any, b: Any, path: str = "") -> None:
    assert type(a) is type(b), (path, type(a), type(b))
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for key in a:
            _assert_same(a[key], b[key], f"{path}.{key}")
    elif isinstance(a, np.ndarray):
        assert (a.dtype, a.shape) == (b.dtype, b.shape), path
        assert a.tobytes() == b.tobytes(), path
    else:
        assert a == b, (path, a, b)


def _check(randomizer: DomainRandomizer, seed: int, episodes: int) -> None:
    fast, ref = np.random.default_rng(seed), np.random.default_rng(seed)
    for _ in range(episodes):
        _assert_same(randomizer.sample(fast), randomizer.sample_reference(ref))
        assert fast.bit_generator.state == ref.bit_generator.state
    # the stream goes on identically after the episodes (nothing over- or under-drawn)
    assert fast.random(4).tobytes() == ref.random(4).tobytes()


@pytest.mark.parametrize("preset", preset_names())
@pytest.mark.parametrize("env_id", ["Sim2Real/Arm3Reach-v0", "Sim2Real/Arm3Pick-v0"])
def test_replayed_draws_are_the_reference_bits(env_id: str, preset: str) -> None:
    randomizer = gym.make(env_id, dr=preset).unwrapped.randomizer
    assert randomizer._plan is not None  # the fast path is the one under test
    listed = {name for name, cat in CATEGORIES.items() if cat.direct is not None}
    taken = {step[0] for step in randomizer._steps if step[5] is not None}
    assert taken == listed  # the listed categories do take their draws straight
    _check(randomizer, seed=11, episodes=60)


def test_a_mixed_preset_with_neutral_keys_replays_the_same() -> None:
    """Neutral keys draw nothing, so uniform runs split and join differently: still the same."""
    env = gym.make("Sim2Real/Arm3Pick-v0", dr="none").unwrapped
    config = DRConfig(
        "mixed",
        {
            "dynamics": {"joint_damping_scale": Range(0.5, 2.0)},
            "visual": {"rgba_jitter": Range(0.0, 0.2), "camera_pos_jitter_m": Range(0.0, 0.01)},
            "object": {"mass_scale": Range(0.5, 0.5), "friction": Range(0.3, 1.9)},
            "kinematics": {"joint_offset_rad": Range(-0.1, 0.1)},
        },
    )
    _check(DomainRandomizer(env.model, env.ids, config), seed=3, episodes=40)


def test_groups_runs_of_uniform_draws_into_one_call_each() -> None:
    plan = DrawPlan(
        [
            ("u", 3, 0.0, 1.0),
            ("u", None, -1.0, 2.0),
            ("n", (2, 3), np.nan, np.nan),
            ("u", (2, 3), -1.0, 1.0),
        ]
    )
    assert [k for k, _ in plan.segments] == ["u", "n", "u"]
    assert plan.segments[0][1].shape == (2, 4)  # low and span for four doubles


def test_a_draw_that_differs_from_the_recording_is_refused() -> None:
    plan = DrawPlan([("u", 3, 0.0, 1.0)])
    replay = plan.replayer(np.random.default_rng(0))
    with pytest.raises(RuntimeError, match=r"DR draw 0 is u4, recorded u3"):
        replay.uniform(0.0, 1.0, 4)
    replay = plan.replayer(np.random.default_rng(0))
    with pytest.raises(RuntimeError, match="0 of 1 recorded draws"):
        replay.done()
