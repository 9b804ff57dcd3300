"""What adapt makes of a fit: the host-side calibration carrying the fitted zero offsets (checked
against a plant's emulator on a real pty), and the DR preset centred on the fit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hardware.firmware.limits import NOMINAL_POT_COUNTS
from hardware.plant import load_plant
from hardware.serial_arm import SerialArm
from hardware.spec import load_spec
from sim2real.adapt.fitted import (
    LINK_FLOOR_M,
    OFFSET_FLOOR_RAD,
    centred_ranges,
    fitted_spec,
    offset_calibration,
)
from sim2real.randomization import DRConfig, load_preset
from sim2real.sysid.kinematics import KinematicFit
from sim2real.sysid.model import ServoFit

SPEC = load_spec()
SERVO = ServoFit(time_constant_s=0.07, max_speed_rad_s=4.0, deadband_rad=0.01, latency_s=0.06)


def _kin(values: np.ndarray, std: np.ndarray) -> KinematicFit:
    return KinematicFit(values, std, np.diag(std**2), rms_m=0.001, n_used=100, n_rejected=0)


def _truth_fit(name: str, std: float = 1e-4) -> KinematicFit:
    plant = load_plant(name)
    L = plant.spec.links
    values = np.r_[plant.offsets_rad()[:3], L.base_height_m, L.upper_arm_m, L.forearm_m]
    return _kin(values, np.full(6, std))


@pytest.mark.parametrize("protocol", ["s2r", "feetech"])
def test_the_offset_calibration_undoes_the_plants_mounting(protocol: str) -> None:
    """The emulator's horns are turned by the plant's offsets; a host on the fitted calibration
    decodes the units of any physical pose back to that physical pose."""
    plant = load_plant("hard")
    cal = offset_calibration(SPEC, protocol, plant.offsets_rad()[:3])
    mounting = plant.mounting(protocol)
    rng = np.random.default_rng(0)
    for _ in range(20):
        physical = rng.uniform(SPEC.actuator_lower_rad + 0.1, SPEC.actuator_upper_rad - 0.1)
        units = mounting.to_units_float(physical)
        np.testing.assert_allclose(cal.from_units(units), physical, atol=1e-9)


@pytest.mark.parametrize("name", ["moderate", "hard"])
def test_on_the_emulated_plant_the_fitted_host_reads_the_physical_angles(name: str) -> None:
    """Through the pty: the nominal host reads physical - offset; the host on the fitted spec and
    calibration connects (its limits fit the firmware's compiled ones) and reads the physical
    angle (within the servo's resolution), and its commands land where the fitted model says."""
    plant = dataclasses.replace(load_plant(name), noise_rad=0.0, droop_rad=0.0)
    kin = _truth_fit(name)
    spec = fitted_spec(SPEC, SERVO, kin)
    cal = offset_calibration(spec, "s2r", kin.joint_offset_rad)
    with plant.emulator("s2r") as emu:
        with SerialArm(SPEC, emu.port, "s2r", host_watchdog_s=None) as arm:
            nominal = arm.read_state().positions_rad
            truth = emu.true_positions_rad()
        with SerialArm(spec, emu.port, "s2r", calibration=cal, host_watchdog_s=None) as arm:
            fitted = arm.read_state().positions_rad
            goal = spec.actuator_home_rad + np.r_[0.1, 0.1, -0.1, 0.0]
            arm.move_to(goal, timeout_s=30.0)
            reached = emu.true_positions_rad()
    # a measured reading is a 10-bit pot read through the firmware's counts -> µs map: one
    # count spans ~3.3 µs, more than the servo's 1 µs resolution
    lo, hi = NOMINAL_POT_COUNTS
    count_rad = (
        (SPEC.servo.pulse_max_us - SPEC.servo.pulse_min_us)
        / (hi - lo)
        * (SPEC.servo.range_rad / (SPEC.servo.pulse_max_us - SPEC.servo.pulse_min_us))
    )
    res = 2 * SPEC.servo.resolution_rad + count_rad / 2
    np.testing.assert_allclose(nominal, truth - plant.offsets_rad(), atol=res)
    np.testing.assert_allclose(fitted, truth, atol=res)
    assert np.abs(nominal - truth).max() > 0.015  # the offsets are visible without the fit
    band = SPEC.servo.deadband_rad + 2 * res
    np.testing.assert_allclose(reached[:3], goal[:3], atol=band)


def test_fitted_limits_stay_inside_the_spec_and_the_firmware_range() -> None:
    kin = _truth_fit("hard")  # elbow one spline tooth (0.2513 rad) off
    spec = fitted_spec(SPEC, SERVO, kin)
    d = kin.joint_offset_rad
    assert np.all(spec.lower_rad >= SPEC.lower_rad) and np.all(spec.upper_rad <= SPEC.upper_rad)
    assert np.all(spec.lower_rad - d >= SPEC.lower_rad) and np.all(
        spec.upper_rad - d <= SPEC.upper_rad
    )
    assert spec.lower_rad[2] == pytest.approx(SPEC.lower_rad[2] + d[2], abs=1e-3)


def test_the_fitted_spec_takes_the_fitted_links_and_servo_figures() -> None:
    kin = _truth_fit("moderate")
    spec = fitted_spec(SPEC, SERVO, kin)
    assert spec.links.upper_arm_m == pytest.approx(kin.values[4], abs=1e-5)
    assert spec.links.tool_forward_m == SPEC.links.tool_forward_m  # unobservable: kept
    assert spec.servo.latency_s == pytest.approx(0.06)
    assert spec.servo.max_speed_rad_s == pytest.approx(4.0)
    assert spec.fingerprint() != SPEC.fingerprint()


def test_centred_ranges_narrow_about_the_fit_with_floors_and_keep_the_rest() -> None:
    trained = load_preset("default").to_dict()
    tight = centred_ranges(trained, SERVO, _truth_fit("mild", std=1e-5), SPEC, 20.0)
    assert tight["kinematics"]["link_length_delta_m"] == [-LINK_FLOOR_M, LINK_FLOOR_M]
    assert tight["kinematics"]["joint_offset_rad"] == [-OFFSET_FLOOR_RAD, OFFSET_FLOOR_RAD]
    assert (
        tight["kinematics"]["tool_offset_delta_m"] == trained["kinematics"]["tool_offset_delta_m"]
    )
    loose = centred_ranges(trained, SERVO, _truth_fit("mild", std=0.002), SPEC, 20.0)
    assert loose["kinematics"]["link_length_delta_m"][1] == pytest.approx(0.006)
    lo, hi = tight["actuation"]["latency_steps"]
    assert lo <= 0.06 * 20.0 <= hi  # the fitted dead time, in control steps
    assert tight["actuation"]["deadband_rad"] == pytest.approx([0.008, 0.012])
    assert tight["actuation"]["action_noise_rad"] == trained["actuation"]["action_noise_rad"]
    assert tight["sensing"] == trained["sensing"] and tight["dynamics"] == trained["dynamics"]
    DRConfig.from_dict("adapt", tight)  # a valid preset
    # a fit that sags (sysid's droop is signed, downwards): the sim's droop is centred on it
    sagging = dataclasses.replace(SERVO, droop_rad=-0.02)
    sag = centred_ranges(trained, sagging, _truth_fit("hard"), SPEC, 20.0)["dynamics"]
    assert sag["actuator_droop_rad"] == pytest.approx([0.016, 0.024])
    assert {k: v for k, v in sag.items() if k != "actuator_droop_rad"} == {
        k: v for k, v in trained["dynamics"].items() if k != "actuator_droop_rad"
    }
