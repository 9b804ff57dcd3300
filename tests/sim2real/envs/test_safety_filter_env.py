"""``safety_filter=True``: the env trains through the host's safety filter, as deployed."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

import sim2real.envs  # noqa: F401
from hardware.safety import WorkspaceGuard


def _env(on: bool) -> gym.Env:  # type: ignore[type-arg]
    return gym.make("Sim2Real/Arm3Pick-v0", dr="none", safety_filter=on)


def test_the_gripper_closes_through_the_per_step_clamp_as_on_the_arm() -> None:
    closes = {}
    for on in (False, True):
        env = _env(on)
        u = env.unwrapped
        env.reset(seed=0)
        grip = u.spec_arm.gripper
        steps = 0
        a = np.zeros(4, dtype=np.float32)
        a[3] = -1.0  # closed, an absolute command
        while u._sent[-1] > grip.closed_rad + 1e-9:
            env.step(a)
            steps += 1
            assert steps < 20
        closes[on] = steps
        env.close()
    clamp = _env(True).unwrapped.spec_arm.safety.max_step_rad
    span = abs(_env(True).unwrapped.spec_arm.gripper.open_rad)
    assert closes[False] == 1
    assert closes[True] == int(np.ceil(span / clamp - 1e-9))


def _below_the_floor(guard: WorkspaceGuard, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """A joint pose inside the limits with the tool or elbow 5 mm or more below the floor."""
    for q1 in np.linspace(lower[1], upper[1], 27):
        for q2 in np.linspace(lower[2], upper[2], 27):
            q = np.array([0.0, q1, q2])
            if guard.excess_m(q) > 0.005:
                return q
    raise AssertionError("no pose below the floor inside the limits")


def test_a_policy_diving_into_the_table_is_held_at_the_guards_floor() -> None:
    sent = {}
    for on in (False, True):
        env = _env(on)
        u = env.unwrapped
        spec = u.spec_arm
        guard = WorkspaceGuard(spec)
        dive = _below_the_floor(guard, spec.lower_rad, spec.upper_rad)
        env.reset(seed=1)
        for _ in range(40):
            a = np.ones(4, dtype=np.float32)
            a[:3] = np.clip((dive - u._targets[:3]) / u.decoder.max_delta_rad, -1.0, 1.0)
            env.step(a)
            if on:  # what reached the servos stays inside, every step
                assert guard.excess_m(u._sent) <= 1e-9
        np.testing.assert_allclose(u._targets[:3], dive, atol=1e-9)  # the policy asked for it
        sent[on] = guard.excess_m(u._sent)
        env.close()
    assert sent[False] > 0.005 and sent[True] <= 1e-9
