"""Deploy options: the sim backend's clock."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from hardware.spec import ArmSpec
from sim2real.deploy import sim_arm
from sim2real.deploy.loop import LoopConfig
from sim2real.deploy.policy_io import PolicyIO
from sim2real.deploy.runner import SIM_CLOCKS, DeployOptions, run_policy
from sim2real.errors import UnknownNameError

from .conftest import ik_policy, pick_policy  # type: ignore[import-not-found]


def test_the_sim_clocks_are_the_sim_arms_and_a_bad_one_is_named() -> None:
    assert SIM_CLOCKS == sim_arm.CLOCKS
    assert DeployOptions(backend="sim").sim_clock == "realtime"
    with pytest.raises(UnknownNameError, match="'wall'"):
        DeployOptions(backend="sim", sim_clock="wall")


def test_lockstep_sim_deploys_do_not_depend_on_how_slow_the_host_is(
    spec: ArmSpec, reach_io: PolicyIO, tmp_path: Path
) -> None:
    """One period of physics per command, as the env steps: a host that stalls between
    commands (a loaded machine) sees exactly the same episode as one that does not."""
    builder, decoder = reach_io.builder, reach_io.decoder
    runs = []
    for stall_s in (0.0, 0.03):
        policy = ik_policy(spec, builder, decoder)

        def slow(
            obs: np.ndarray,
            policy: Callable[[np.ndarray], np.ndarray] = policy,
            stall_s: float = stall_s,
        ) -> np.ndarray:
            time.sleep(stall_s)  # a stall inside the period, not a rate the test relies on
            return policy(obs)

        log = tmp_path / f"run{stall_s}.npz"
        run_policy(
            slow, reach_io, spec, DeployOptions(backend="sim", sim_clock="lockstep"),
            LoopConfig(episodes=1, seed=3), log_path=log,
        )  # fmt: skip
        runs.append(np.load(log))
    np.testing.assert_array_equal(runs[0]["joints_rad"], runs[1]["joints_rad"])
    np.testing.assert_allclose(runs[0]["obs"], runs[1]["obs"], rtol=0, atol=1e-12)


class _NoSleep:
    """``time`` for one module, whose ``sleep`` fails the test: the lockstep world waits for
    the loop, so nothing on its path may wait for the wall clock."""

    def __getattr__(self, name: str) -> object:
        return getattr(time, name)

    @staticmethod
    def sleep(seconds: float) -> None:
        raise AssertionError(f"slept {seconds:.3f} s on a lockstep simulator's path")


def test_a_lockstep_deploy_never_sleeps(
    spec: ArmSpec, pick_io: PolicyIO, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The loop's periods, the last period's judgement, ``move_to`` (home, park, the put-down)
    and the wait for still objects all run on the simulator's time."""
    from hardware import arm as arm_mod
    from sim2real.deploy import clock as clock_mod
    from sim2real.deploy import session as session_mod

    for module in (arm_mod, clock_mod, session_mod):
        monkeypatch.setattr(module, "time", _NoSleep())
    monkeypatch.setattr(session_mod, "sleep_until", _NoSleep.sleep)
    result = run_policy(
        pick_policy(spec, pick_io.builder, pick_io.decoder), pick_io, spec,
        DeployOptions(backend="sim", sim_clock="lockstep"), LoopConfig(episodes=2),
    )  # fmt: skip
    assert result.stopped_early is None and len(result.episodes) == 2
