"""Arm3Env's command-side observation: ``joint_target`` is what was sent, not what was read."""

from __future__ import annotations

import numpy as np

import sim2real.envs as envs
from sim2real.randomization.config import DRConfig


def _fields(env: object, obs: np.ndarray) -> dict[str, np.ndarray]:
    return env.unwrapped.builder.split(obs)  # type: ignore[attr-defined,no-any-return]


def test_joint_target_integrates_the_decoded_actions_and_leads_a_lagging_servo() -> None:
    dr = DRConfig.from_dict("lag2", {"actuation": {"latency_steps": [2, 2]}})
    env = envs.make("reach", dr=dr, max_delta_rad=0.05)
    obs, _ = env.reset(seed=3)
    f = _fields(env, obs)
    # At rest on reset (readings are quantised to the servo resolution).
    np.testing.assert_allclose(f["joint_target"], f["joint_pos"], atol=1e-3)
    start = f["joint_target"].copy()
    action = np.array([1.0, -0.5, 0.25], dtype=np.float32)
    for k in range(1, 3):
        obs, *_ = env.step(action)
        f = _fields(env, obs)
        np.testing.assert_allclose(f["joint_target"], start + k * 0.05 * action, atol=1e-6)
    # Two steps of latency: the servo has not started moving, the command has.
    np.testing.assert_allclose(f["joint_pos"], start, atol=0.01)  # only settling under gravity
    assert np.abs(f["joint_target"] - f["joint_pos"]).max() > 0.09
    env.close()
