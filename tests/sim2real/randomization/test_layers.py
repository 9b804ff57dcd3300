"""The servo actuation and sensor layers do what the hardware does."""

from __future__ import annotations

import numpy as np
import pytest

from hardware.spec import load_spec
from sim2real.actuation import ServoActuation
from sim2real.randomization.sensing import SensorModel

SPEC = load_spec()


def _servo(**params: float) -> ServoActuation:
    s = ServoActuation(SPEC, 0.05, 3)
    base = {
        "latency_steps": 0,
        "action_noise_rad": 0.0,
        "max_speed_scale": 1.0,
        "deadband_rad": 0.0,
        "quantisation_rad": 0.0,
    }
    base.update(params)
    s.configure(base)
    s.reset(np.zeros(3))
    return s


def test_speed_limit_caps_the_target_change_per_step() -> None:
    s = _servo(max_speed_scale=0.5)
    out = s(np.array([1.0, -1.0, 0.01]), np.random.default_rng(0))
    cap = SPEC.servo.max_speed_rad_s * 0.5 * 0.05
    np.testing.assert_allclose(out, [cap, -cap, 0.01])


def test_deadband_ignores_small_changes_and_quantisation_rounds() -> None:
    s = _servo(deadband_rad=0.01, quantisation_rad=0.002)
    rng = np.random.default_rng(0)
    np.testing.assert_allclose(s(np.array([0.005, 0.02, -0.0099]), rng), [0.0, 0.02, 0.0])
    out = s(np.array([0.0, 0.0333, 0.0]), rng)
    assert out[1] == pytest.approx(0.034)


def test_latency_delays_commands_by_whole_steps() -> None:
    s = _servo(latency_steps=2)
    rng = np.random.default_rng(0)
    outs = [s(np.full(3, 0.1 * (i + 1)), rng)[0] for i in range(4)]
    np.testing.assert_allclose(outs, [0.0, 0.0, 0.1, 0.2])


def test_stereo_noise_matches_the_depth_formula_in_notes() -> None:
    """σ_z = Z²·σ_d/(f·B): 0.5 m, f = 550 px, B = 0.08 m, 0.2 px → about 1.6 mm."""
    R = np.eye(3)
    m = SensorModel(3, 0.0, R, np.zeros(3), focal_px=550.0, baseline_m=0.08)
    params = {
        "joint_noise_rad": 0.0,
        "joint_bias_rad": np.zeros(3),
        "stereo_pixel_noise_px": 0.2,
        "position_bias_m": np.zeros(3),
        "obs_delay_steps": 0,
    }
    m.configure(params)
    p = np.tile([0.0, 0.0, 0.5], (20000, 1))
    est = m.read_points(p, np.random.default_rng(0))
    sd = (est - p).std(axis=0)
    expected_z = 0.5**2 * np.sqrt(2) * 0.2 / (550 * 0.08)
    assert sd[2] == pytest.approx(expected_z, rel=0.05)
    assert sd[0] == pytest.approx(0.5 * 0.2 / 550, rel=0.05)
    assert 1.3e-3 < expected_z < 2.2e-3


def test_joint_readings_are_quantised_to_servo_resolution() -> None:
    m = SensorModel(3, 0.01, np.eye(3), np.zeros(3), 550.0, 0.08)
    out = m.read_joints(np.array([0.123, -0.456, 0.0049]), np.random.default_rng(0))
    np.testing.assert_allclose(out, [0.12, -0.46, 0.0])
