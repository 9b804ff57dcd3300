"""Kinematic calibration: recovers a known plant's joint offsets and link lengths from the wrist
marker, through rendered frames, ArUco detection and triangulation (a short excitation), with an
honest uncertainty; the CLI writes the fitted spec and the estimated plant; bad logs fail in one
line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hardware.plant import Plant, load_plant
from hardware.spec import ArmSpec, load_spec
from sim2real.errors import ConfigError
from sim2real.sysid.kinematics import (
    MarkerObservations,
    excitation_rad,
    fit_kinematics,
    load_marker_log,
    marker_p_tool_m,
    observe_rendered,
    predict_marker_m,
)

ROOT = Path(__file__).resolve().parents[3]
SPEC = load_spec()


def _truth(plant: Plant) -> np.ndarray:
    L = plant.spec.links
    return np.r_[plant.offsets_rad()[:3], L.base_height_m, L.upper_arm_m, L.forearm_m]


def _synthetic(plant: Plant, seconds: float, noise_m: float, seed: int) -> MarkerObservations:
    q = excitation_rad(SPEC, seconds, 10.0)
    rng = np.random.default_rng(seed)
    p = predict_marker_m(_truth(plant), q, SPEC) + rng.normal(0.0, noise_m, (len(q), 3))
    p[::37] += 0.04  # a marker decoded at the wrong corner now and then
    return MarkerObservations(q, p, source="synthetic")


def test_excitation_keeps_the_tool_above_the_table_by_spec_and_by_every_plant() -> None:
    q = excitation_rad(SPEC, 60.0, 10.0)
    assert np.all(q >= SPEC.lower_rad) and np.all(q <= SPEC.upper_rad)
    assert np.ptp(q, axis=0).min() > 0.6  # every joint moves a lot
    for name in ("mild", "moderate", "hard"):
        plant = load_plant(name)
        for spec, offsets in ((SPEC, np.zeros(3)), (plant.spec, plant.offsets_rad()[:3])):
            z = [spec.forward_kinematics(x + offsets)[2] for x in q[::5]]
            assert min(z) > 0.01, name


def test_fit_recovers_a_known_plant_with_an_honest_uncertainty() -> None:
    plant = load_plant("hard")
    fit = fit_kinematics(_synthetic(plant, 30.0, 0.001, seed=1), SPEC)
    err = fit.values - _truth(plant)
    assert np.all(np.abs(err[:3]) < 0.005) and np.all(np.abs(err[3:]) < 0.001)
    assert np.all(np.abs(err) < 5 * fit.std)  # the covariance is not over-confident ...
    assert np.all(fit.std[3:] < 0.0005)  # ... nor useless
    assert fit.n_rejected >= 8 and fit.rms_m == pytest.approx(np.sqrt(3) * 0.001, rel=0.2)


def test_fit_through_rendered_frames_detection_and_triangulation() -> None:
    """The CI version of bench/kinematic_calibration.py: a 15 s excitation at 8 Hz."""
    plant = load_plant("hard")
    q = excitation_rad(SPEC, 15.0, 8.0)
    obs, seen = observe_rendered(plant, q, np.random.default_rng(0))
    assert seen.mean() > 0.7
    fit = fit_kinematics(obs, SPEC)
    err = fit.values - _truth(plant)
    assert np.all(np.abs(err[:3]) < 0.005), err
    assert np.all(np.abs(err[3:]) < 0.001), err


def test_a_still_arm_does_not_separate_the_parameters() -> None:
    q = np.tile(SPEC.home_rad, (50, 1))
    p = predict_marker_m(_truth(Plant.nominal(SPEC)), q, SPEC)
    with pytest.raises(ConfigError, match="does not separate"):
        fit_kinematics(MarkerObservations(q, p, source="still"), SPEC)


def _write_log(path: Path, obs: MarkerObservations, key: str, spec: ArmSpec) -> Path:
    q = obs.joints_rad
    if key == "ee_marker_m":
        ee = obs.marker_m
    else:  # what the deploy loop logs: the plate plus the spec's plate-to-tool offset by yaw
        yaw = spec.joints[0].sign * q[:, 0]
        dx, dy, dz = marker_p_tool_m(spec)
        c, s = np.cos(yaw), np.sin(yaw)
        off = np.stack([c * dx - s * dy, s * dx + c * dy, np.full_like(c, dz)], axis=1)
        ee = obs.marker_m + off
    ee = ee.copy()
    seen = np.ones(len(q), dtype=bool)
    seen[5:9] = False  # periods without a detection: NaN raw, forward kinematics in ee_est_m
    ee[5:9] = np.nan if key == "ee_marker_m" else [SPEC.forward_kinematics(x) for x in q[5:9]]
    extra = {"ee_seen": seen} if key == "ee_est_m" else {}
    joints = np.c_[q, np.zeros(len(q))]
    np.savez(path, t_s=np.arange(len(q)) * 0.05, joints_rad=joints, **{key: ee}, **extra)
    return path


@pytest.mark.parametrize("key", ["ee_marker_m", "ee_est_m"])
def test_log_adapter_reads_raw_markers_and_deploy_tool_estimates(tmp_path: Path, key: str) -> None:
    obs = _synthetic(load_plant("moderate"), 10.0, 0.0005, seed=2)
    loaded = load_marker_log(_write_log(tmp_path / "log.npz", obs, key, SPEC), SPEC)
    assert len(loaded.joints_rad) == len(obs.joints_rad) - 4
    np.testing.assert_allclose(loaded.marker_m[:5], obs.marker_m[:5], atol=1e-12)


def test_markers_pair_with_the_readings_at_their_own_instants(tmp_path: Path) -> None:
    """A view 30 ms behind its readings (a loaded host, a camera's latency) on a 6 s sweep:
    paired by period the fit takes the lag for joint offsets; with ``marker_t_s`` the readings
    are interpolated to each frame's instant and the offsets come back."""
    truth = _truth(load_plant("moderate"))
    fine = excitation_rad(SPEC, 6.1, 1000.0)  # the sweep every ms
    read_ms, lag_ms = np.arange(0, 6000, 100), 30
    q_read = fine[read_ms]
    marker = predict_marker_m(truth, fine[read_ms + lag_ms], SPEC)  # where the wrist was then
    joints = np.c_[q_read, np.zeros(len(q_read))]
    t_s = 100.0 + read_ms / 1000.0  # time.monotonic() is anywhere
    by_period, stamped = tmp_path / "by_period.npz", tmp_path / "stamped.npz"
    np.savez(by_period, t_s=t_s, joints_rad=joints, ee_marker_m=marker)
    np.savez(
        stamped, t_s=t_s, marker_t_s=t_s + lag_ms / 1000, joints_rad=joints, ee_marker_m=marker
    )
    off = fit_kinematics(load_marker_log(by_period, SPEC), SPEC).values[:3] - truth[:3]
    assert np.abs(off).max() > 0.01, off  # the lag, fitted as offsets
    obs = load_marker_log(stamped, SPEC)
    assert len(obs.joints_rad) == len(t_s) - 1  # the last frame is after the last reading
    off = fit_kinematics(obs, SPEC).values[:3] - truth[:3]
    assert np.abs(off).max() < 0.001, off
    np.savez(stamped, t_s=t_s[::-1], marker_t_s=t_s, joints_rad=joints, ee_marker_m=marker)
    with pytest.raises(ConfigError, match=r"reading times 't_s' do not increase"):
        load_marker_log(stamped, SPEC)


def _sysid(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "sim2real", "sysid", *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )


def test_cli_writes_the_fitted_spec_and_the_estimated_plant(tmp_path: Path) -> None:
    plant = load_plant("hard")
    log = _write_log(tmp_path / "deploy.npz", _synthetic(plant, 30.0, 0.001, 3), "ee_est_m", SPEC)
    out = tmp_path / "fitted.yaml"
    res = _sysid("--kinematics", str(log), "--out", str(out), "--json")
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    fitted = ArmSpec.from_yaml(out)
    assert fitted.links.forearm_m == pytest.approx(plant.spec.links.forearm_m, abs=0.001)
    assert fitted.servo == SPEC.servo and fitted.joints == SPEC.joints
    estimated = load_plant(summary["plant"])
    estimated.check_against(SPEC)
    np.testing.assert_allclose(estimated.offsets_rad(), plant.offsets_rad(), atol=0.005)
    assert "+-" in out.read_text().splitlines()[1]  # the uncertainty is in the header
    assert summary["kinematics"]["upper_arm_m_std"] < 0.0005


def test_a_log_without_marker_observations_is_a_one_line_error(tmp_path: Path) -> None:
    log = tmp_path / "blind.npz"
    np.savez(log, t_s=np.zeros(30), joints_rad=np.zeros((30, 4)))
    out = tmp_path / "fitted.yaml"
    res = _sysid("--kinematics", str(log), "--out", str(out))
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert "has no wrist-marker observations" in lines[0] and str(log) in lines[0]
    assert not out.exists() and not (tmp_path / "fitted.plant.yaml").exists()
    est_only = tmp_path / "est.npz"
    np.savez(est_only, joints_rad=np.zeros((30, 4)), ee_est_m=np.zeros((30, 3)))
    with pytest.raises(ConfigError, match=r"has 'ee_est_m' but no 'ee_seen'"):
        load_marker_log(est_only, SPEC)
    all_nan = tmp_path / "unseen.npz"
    np.savez(all_nan, joints_rad=np.zeros((30, 4)), ee_marker_m=np.full((30, 3), np.nan))
    with pytest.raises(ConfigError, match=r"0 periods with a wrist-marker observation"):
        load_marker_log(all_nan, SPEC)
