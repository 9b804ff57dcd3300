"""Sysid on a mock arm that is not the spec: ``sysid --record --backend mock --plant hard``
records over the pty emulator built from the plant, and the servo fit recovers the plant's
figures (not the spec's)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from hardware.plant import load_plant
from hardware.spec import load_spec
from sim2real.sysid.fit import fit_servo, load_log

ROOT = Path(__file__).resolve().parents[3]
SPEC = load_spec()


def _sysid(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "sim2real", "sysid", *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )


@pytest.mark.slow
def test_servo_fit_recovers_the_hard_plant_not_the_spec(tmp_path: Path) -> None:
    log = tmp_path / "hard.npz"
    res = _sysid(
        "--record", str(log), "--backend", "mock", "--protocol", "feetech", "--plant", "hard"
    )
    assert res.returncode == 0, res.stderr
    fit, _ = fit_servo([load_log(log, SPEC.n_joints)], SPEC, fit_droop=True)
    plant = load_plant("hard")
    truth = plant.spec.servo
    assert fit.max_speed_rad_s == pytest.approx(truth.max_speed_rad_s, rel=0.1)
    assert fit.time_constant_s == pytest.approx(truth.time_constant_s, rel=0.1)
    assert fit.deadband_rad == pytest.approx(truth.deadband_rad, rel=0.15)
    assert -fit.droop_rad == pytest.approx(plant.droop_rad, rel=0.15)
    # the plant's command latency plus the bus round trip the host sees
    assert plant.command_latency_s - 0.005 <= fit.latency_s <= plant.command_latency_s + 0.015


def test_plant_needs_the_mock_backend(tmp_path: Path) -> None:
    res = _sysid("--record", str(tmp_path / "x.npz"), "--backend", "serial", "--plant", "hard")
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2 and len(lines) == 1 and "use it with --backend mock" in lines[0]
    assert not (tmp_path / "x.npz").exists()
