"""KalmanTracker: hand-built F/H/Q, gating, predict-only misses, re-initialisation, latency."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.common import kinematic_kf

from calibration.errors import ConfigError, UnknownNameError
from calibration.kalman import (
    KalmanTracker,
    TrackerConfig,
    measurement_matrix,
    process_noise,
    transition_matrix,
)
from calibration.synthetic import rotation
from calibration.triangulate import quaternion_from_matrix

SIGMA_M = 0.002


def test_measurement_matrix_observes_each_axis_once() -> None:
    """filterpy 2.0.0's kinematic_kf builds H with x+y+z summed in every row; ours does not."""
    for order in (1, 2):
        H = measurement_matrix(order)
        state = np.arange(1.0, 3 * (order + 1) + 1)
        np.testing.assert_array_equal(H @ state, [1.0, 2.0, 3.0])
    broken = kinematic_kf(dim=3, order=1, dim_z=3).H
    assert not np.array_equal(broken, measurement_matrix(1))  # the trap is still there


def test_transition_and_noise_are_kinematic() -> None:
    dt = 0.07
    p, v, a = np.array([0.1, -0.2, 0.3]), np.array([1.0, 2.0, -1.0]), np.array([0.5, 0.0, -2.0])
    np.testing.assert_allclose(transition_matrix(dt, 1) @ np.r_[p, v], np.r_[p + v * dt, v])
    np.testing.assert_allclose(
        transition_matrix(dt, 2) @ np.r_[p, v, a],
        np.r_[p + v * dt + 0.5 * a * dt**2, v + a * dt, a],
    )
    Q = process_noise(dt, 1, 2.0)
    np.testing.assert_allclose(Q[0, 0], 4.0 * dt**4 / 4)  # position variance of one axis
    np.testing.assert_allclose(Q[0, 3], 4.0 * dt**3 / 2)  # its covariance with velocity
    assert Q[0, 1] == 0.0  # axes independent
    assert np.all(np.linalg.eigvalsh(process_noise(dt, 2, 1.0)) > -1e-15)


@pytest.mark.parametrize(
    "config", [TrackerConfig(), TrackerConfig(model="cv", manoeuvre_std=None, process_std=0.3)]
)
def test_tracks_constant_velocity_with_irregular_timestamps(config: TrackerConfig) -> None:
    rng = np.random.default_rng(0)
    tracker = KalmanTracker(config)
    p0, vel = np.array([0.1, 0.0, 0.5]), np.array([0.05, -0.02, 0.01])
    t = 0.0
    errors, velocities = [], []
    for k in range(300):
        t += rng.uniform(0.02, 0.09)  # jittery frame times
        est = tracker.update(p0 + vel * t + rng.normal(0, SIGMA_M, 3), t)
        assert est.status in (("initialised",) if k == 0 else ("updated", "rejected"))
        if k >= 100:
            errors.append(est.position_m - (p0 + vel * t))
            velocities.append(est.velocity_mps)
    rms_m = float(np.sqrt(np.mean(np.sum(np.square(errors), axis=1))))
    assert rms_m < 0.8 * SIGMA_M * math.sqrt(3)  # below the raw 3-D noise
    np.testing.assert_allclose(np.mean(velocities, axis=0), vel, atol=0.005)
    # a 99.9% gate rejects about one good measurement in a thousand, never a run of them
    assert tracker.stats.reinitialised == 0 and tracker.stats.rejected <= 3


def test_outlier_is_gated_before_it_touches_the_state() -> None:
    rng = np.random.default_rng(1)
    tracker = KalmanTracker()
    target = np.array([0.0, 0.1, 0.5])
    for k in range(60):
        tracker.update(target + rng.normal(0, SIGMA_M, 3), k * 0.05)
    expected = tracker.predict_at(60 * 0.05)
    est = tracker.update(target + [0.03, 0.0, 0.0], 60 * 0.05)
    assert est.status == "rejected" and est.nis is not None and est.nis > 16.27
    np.testing.assert_allclose(est.position_m, expected.position_m)
    assert tracker.consecutive_rejections == 1
    est = tracker.update(target, 61 * 0.05)
    assert est.status == "updated" and tracker.consecutive_rejections == 0


def test_reinitialises_after_consecutive_rejections_on_a_real_jump() -> None:
    """The target really moved 30 cm: after max_rejections the track restarts there, and one
    wild outlier among the rejected measurements does not decide where."""
    rng = np.random.default_rng(2)
    config = TrackerConfig(max_rejections=5)
    tracker = KalmanTracker(config)
    for k in range(40):
        tracker.update(np.array([0.0, 0.0, 0.5]) + rng.normal(0, SIGMA_M, 3), k * 0.05)
    jumped = np.array([0.3, 0.0, 0.5])
    statuses = []
    for k in range(40, 45):
        z = jumped + (np.array([0.0, 0.2, 0.0]) if k == 42 else rng.normal(0, SIGMA_M, 3))
        statuses.append(tracker.update(z, k * 0.05).status)
    assert statuses == ["rejected"] * 4 + ["reinitialised"]
    est = tracker.update(jumped + rng.normal(0, SIGMA_M, 3), 45 * 0.05)
    assert est.status == "updated"
    np.testing.assert_allclose(est.position_m, jumped, atol=0.004)


def test_missed_detections_predict_then_lose_the_track() -> None:
    tracker = KalmanTracker(TrackerConfig(max_coast_s=0.3))
    vel = np.array([0.1, 0.0, 0.0])
    for k in range(40):
        tracker.update(vel * k * 0.05, k * 0.05)
    last = tracker.predict_at(39 * 0.05)
    est = tracker.predict(40 * 0.05)
    assert est.status == "predicted" and est.valid
    np.testing.assert_allclose(est.position_m, vel * 40 * 0.05, atol=0.001)
    assert np.all(est.position_std_m > last.position_std_m)  # uncertainty grows while coasting
    est = tracker.predict(46 * 0.05)
    assert est.status == "lost" and not est.valid and not tracker.initialised
    est = tracker.update(np.array([0.3, 0.0, 0.0]), 47 * 0.05)
    assert est.status == "initialised"


def test_predict_at_extrapolates_without_changing_state() -> None:
    tracker = KalmanTracker()
    assert tracker.predict_at(0.0).status == "uninitialised"
    vel = np.array([0.0, 0.2, 0.0])
    for k in range(60):
        tracker.update(vel * k * 0.05, k * 0.05)
    ahead = tracker.predict_at(59 * 0.05 + 0.1)  # 100 ms of latency compensated
    np.testing.assert_allclose(ahead.position_m, vel * (59 * 0.05 + 0.1), atol=0.002)
    now = tracker.predict_at(59 * 0.05)
    assert tracker.predict_at(59 * 0.05 + 0.1).position_m == pytest.approx(ahead.position_m)
    assert now.position_m == pytest.approx(tracker.predict_at(59 * 0.05).position_m)


def test_timestamps_must_not_go_backwards() -> None:
    tracker = KalmanTracker()
    tracker.update(np.zeros(3), 1.0)
    with pytest.raises(ConfigError, match="before the previous one"):
        tracker.update(np.zeros(3), 0.5)


def test_nan_measurement_is_a_miss() -> None:
    tracker = KalmanTracker()
    tracker.update(np.zeros(3), 0.0)
    assert tracker.update(np.full(3, np.nan), 0.05).status == "predicted"


def test_orientation_is_smoothed_and_sign_safe() -> None:
    tracker = KalmanTracker(TrackerConfig(orientation_time_constant_s=0.1))
    q_a = quaternion_from_matrix(rotation(0, 0, 0))
    q_b = quaternion_from_matrix(rotation(0, 0, 40))
    tracker.update(np.zeros(3), 0.0, q_a)
    est = tracker.update(np.zeros(3), 0.05, -q_b)  # same rotation as q_b, opposite sign
    angle = math.degrees(2 * math.acos(min(1.0, abs(float(np.dot(est.orientation_wxyz, q_a))))))
    assert 10.0 < angle < 25.0  # moved part of the way: 1 - exp(-0.5) ≈ 39% of 40°
    for k in range(2, 40):
        est = tracker.update(np.zeros(3), k * 0.05, q_b)
    assert abs(float(np.dot(est.orientation_wxyz, q_b))) == pytest.approx(1.0, abs=1e-6)


def test_config_validation() -> None:
    with pytest.raises(UnknownNameError, match="valid: ca, cv"):
        TrackerConfig(model="jerk")
    with pytest.raises(ConfigError, match="measurement_std_m"):
        TrackerConfig(measurement_std_m=0.0)
    with pytest.raises(ConfigError, match="max_rejections"):
        TrackerConfig(max_rejections=1)
