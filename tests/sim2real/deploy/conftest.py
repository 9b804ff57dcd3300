"""Shared pieces for deploy tests: a scripted IK policy that speaks the observation contract."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np
import pytest

import sim2real.envs  # noqa: F401
from hardware.spec import ArmSpec, load_spec
from sim2real.observation import ActionDecoder, ObservationBuilder


@pytest.fixture(scope="session")
def spec() -> ArmSpec:
    return load_spec()


@pytest.fixture(scope="session")
def reach_contract() -> tuple[ObservationBuilder, ActionDecoder]:
    env = gym.make("Sim2Real/Arm3Reach-v0", dr="none")
    u = env.unwrapped
    out = (u.builder, u.decoder)
    env.close()
    return out


def ik_policy(
    spec: ArmSpec, builder: ObservationBuilder, decoder: ActionDecoder, gain: float = 0.4
) -> Callable[[np.ndarray], np.ndarray]:
    """Reads joints and the goal estimate from the observation by the documented layout and
    servoes towards the IK solution: a policy that only works if the contract holds."""
    sl = {f.name: slice(f.start, f.stop) for f in builder.layout()}

    def policy(obs: np.ndarray) -> np.ndarray:
        q = obs[sl["joint_pos"]]
        q_goal = spec.inverse_kinematics(obs[sl["goal_pos"]])
        if q_goal is None:
            return np.zeros(decoder.n_actions)
        return np.clip(gain * (q_goal - q) / decoder.max_delta_rad, -1.0, 1.0)

    return policy
