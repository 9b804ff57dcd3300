"""Shared pieces for the learning-on-the-arm tests."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from timescale import scaled

from hardware.spec import ArmSpec, load_spec
from sim2real.deploy.policy_io import PolicyIO, io_for

# mock runs: a relaxed watchdog (pytest -n 2 on a loaded machine may run a period long: these
# tests judge the chain, not the timing) and a generous wait for the first sighting; the cameras
# at the loop's rate (tests/sim2real/deploy/conftest.py says why)
MOCK = {"backend": "mock", "watchdog_s": scaled(2.0), "camera_fps": 20.0}


@pytest.fixture(scope="session")
def spec() -> ArmSpec:
    return load_spec()


@pytest.fixture(scope="session")
def reach_io(spec: ArmSpec) -> PolicyIO:
    return io_for(spec, "Sim2Real/Arm3Reach-v0")


@pytest.fixture(scope="session")
def pick_io(spec: ArmSpec) -> PolicyIO:
    return io_for(spec, "Sim2Real/Arm3Pick-v0")


def ik_reach(spec: ArmSpec, io: PolicyIO, gain: float = 0.4) -> Callable[[np.ndarray], np.ndarray]:
    """Servoes the commanded joints towards the IK solution of the observed goal, reading the
    observation by its documented layout: it reaches only if the env's contract holds."""
    sl = {f.name: slice(f.start, f.stop) for f in io.builder.layout()}

    def act(obs: np.ndarray) -> np.ndarray:
        q = obs[sl["joint_target"]]
        q_goal = spec.inverse_kinematics(obs[sl["goal_pos"]])
        if q_goal is None:
            return np.zeros(io.decoder.n_actions, dtype=np.float32)
        a = gain * (q_goal - q) / io.decoder.max_delta_rad
        return np.clip(a, -1.0, 1.0).astype(np.float32)

    return act
