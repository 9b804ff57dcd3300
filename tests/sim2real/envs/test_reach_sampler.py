"""``ReachableSampler`` (the reach reset's target draw) against ``sample_reachable``, its
reference: the same targets, bit for bit, and the generator left in the same state."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hardware.spec import load_spec
from sim2real.envs.reach import ReachableSampler
from sim2real.envs.workspace import sample_reachable

SPEC = load_spec()


@pytest.mark.parametrize("min_height_m", [0.03, 0.12])
def test_the_same_targets_and_generator_state_as_the_reference(min_height_m: float) -> None:
    sampler = ReachableSampler(SPEC, min_height_m)
    fast, ref = np.random.default_rng(4), np.random.default_rng(4)
    for _ in range(500):
        a = sampler.sample(fast)
        b = sample_reachable(SPEC, ref, min_height_m)
        assert (a.dtype, a.shape) == (b.dtype, b.shape)
        assert a.tobytes() == b.tobytes()
        assert fast.bit_generator.state == ref.bit_generator.state


def test_flipped_joint_signs_follow_the_spec() -> None:
    joints = tuple(replace(j, axis=f"-{j.axis.lstrip('-')}") for j in SPEC.joints)
    spec = replace(SPEC, joints=joints)
    fast, ref = np.random.default_rng(9), np.random.default_rng(9)
    for _ in range(200):
        assert (
            ReachableSampler(spec).sample(fast).tobytes() == sample_reachable(spec, ref).tobytes()
        )


def test_an_unreachable_height_is_refused_with_the_spec_named() -> None:
    with pytest.raises(RuntimeError, match=r"no reachable point above 5\.0 m"):
        ReachableSampler(SPEC, 5.0).sample(np.random.default_rng(0))
