"""The whole mock chain on the simulated chip: ``deploy --backend mock --firmware avr`` runs the
AVR binary in simavr behind the same pty, with MuJoCo physics and rendered cameras."""

from __future__ import annotations

import os

import pytest
from timescale import scaled  # type: ignore[import-not-found]

from hardware.firmware import avr
from hardware.spec import ArmSpec
from sim2real.deploy.loop import LoopConfig
from sim2real.deploy.policy_io import PolicyIO
from sim2real.deploy.runner import DeployOptions, run_policy

from .conftest import MOCK, ik_policy  # type: ignore[import-not-found]

_MISSING = avr.missing_toolchain()
_REQUIRED = os.environ.get("SIM2REAL_REQUIRE_AVR") == "1"  # CI: a missing toolchain fails
pytestmark = pytest.mark.skipif(_MISSING is not None and not _REQUIRED, reason=_MISSING or "")


@pytest.mark.realtime
def test_a_reach_runs_on_the_simulated_chip(spec: ArmSpec, reach_io: PolicyIO) -> None:
    avr.build()
    result = run_policy(
        ik_policy(spec, reach_io.builder, reach_io.decoder), reach_io, spec,
        DeployOptions(**{**MOCK, "firmware": "avr"}),
        LoopConfig(episodes=1, start_timeout_s=scaled(60)),
    )  # fmt: skip
    assert result.stopped_early is None
    assert result.arm.emulator.firmware == "AvrEmulator"  # served in the mock arm's process
    assert result.arm.emulator.applied(), "the chip applied no command"
    assert result.episodes[0].distance_m < 0.05  # the arm moved to the target through the chip
