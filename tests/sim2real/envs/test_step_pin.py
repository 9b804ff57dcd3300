"""The arm envs' step path is bit-for-bit what the shipped policies were trained and measured on.

``tests/data/step_pin/env_rollouts_v2.npz`` holds seeded rollouts (default DR, random actions, a
reset part-way, the held start for pick) recorded before the step path was made faster (see the
README there). This test replays them and demands the same observations, rewards, flags and
info figures, to the bit: a faster step must not change what a policy sees.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import sim2real.envs as envs

PIN = Path(__file__).parents[2] / "data" / "step_pin" / "env_rollouts_v2.npz"
CASES: dict[str, tuple[str, dict[str, Any], dict[str, Any] | None]] = {
    # name: (env id, env kwargs, reset options of the second episode)
    "reach": ("Sim2Real/Arm3Reach-v0", {}, None),
    "reach_strong": ("Sim2Real/Arm3Reach-v0", {"dr": "strong"}, None),
    "pick": ("Sim2Real/Arm3Pick-v0", {}, {"start": "held"}),
    "trace": ("Sim2Real/Arm3Trace-v0", {}, None),
    "reach_goal": ("Sim2Real/Arm3ReachGoal-v0", {}, None),
}
STEPS, RESET_AT = 90, 60
INFO_KEYS = ("is_success", "distance_m")


def _flat(obs: Any) -> np.ndarray:
    if isinstance(obs, dict):
        return np.concatenate([np.asarray(obs[k], dtype=np.float64).ravel() for k in sorted(obs)])
    return np.asarray(obs, dtype=np.float64).ravel()


def rollout(name: str) -> dict[str, np.ndarray]:
    """Observations, rewards, terminated/truncated and info figures of one seeded rollout."""
    env_id, kwargs, second = CASES[name]
    env = envs.make(env_id, **kwargs)
    rng = np.random.default_rng(11)
    obs, _ = env.reset(seed=1234)
    rows, rewards, flags, infos = [_flat(obs)], [], [], []
    try:
        for i in range(STEPS):
            if i == RESET_AT:
                obs, _ = env.reset(seed=99, options=second)
                rows.append(_flat(obs))
            action = rng.uniform(-1.0, 1.0, env.action_space.shape).astype(np.float32)
            obs, reward, term, trunc, info = env.step(action)
            rows.append(_flat(obs))
            rewards.append(float(reward))
            flags.append((bool(term), bool(trunc)))
            infos.append([float(info.get(k, np.nan)) for k in INFO_KEYS])
    finally:
        env.close()
    return {
        "obs": np.array(rows),
        "rewards": np.array(rewards),
        "flags": np.array(flags),
        "infos": np.array(infos),
    }


@pytest.mark.parametrize("name", sorted(CASES))
def test_a_seeded_rollout_is_what_it_was(name: str) -> None:
    pinned = np.load(PIN)
    got = rollout(name)
    for key, value in got.items():
        np.testing.assert_array_equal(value, pinned[f"{name}/{key}"], err_msg=f"{name} {key}")


def record() -> None:  # pragma: no cover - run once, by hand, on the reference code
    arrays = {f"{n}/{k}": v for n in CASES for k, v in rollout(n).items()}
    np.savez_compressed(PIN, **arrays)


if __name__ == "__main__":  # pragma: no cover
    record()
