"""StereoMarkerTracker: rendered frame pairs in, filtered marker pose in the arm base frame out."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.errors import ConfigError
from calibration.perception import StereoMarkerTracker
from calibration.registration import transform_points
from calibration.synthetic import RenderNoise, facing_camera, pose, render_marker, rotation
from calibration.triangulate import StereoRig, quaternion_from_matrix

LENGTH_M = 0.04
BASE_T_CAM = pose(rotation(-115.0, 2.0, 88.0), [0.30, -0.02, 0.45])


def _frames(rig: StereoRig, left_T_marker: np.ndarray, rng: np.random.Generator):
    noise = RenderNoise(pixel_std=1.5, blur_sigma_px=0.6)
    return tuple(
        render_marker(
            cam, T @ left_T_marker, rng, marker_id=5, marker_length_m=LENGTH_M, noise=noise
        )
        for cam, T in ((rig.left, np.eye(4)), (rig.right, rig.right_T_left))
    )


def test_tracks_a_moving_marker_in_the_base_frame(rig: StereoRig) -> None:
    rng = np.random.default_rng(0)
    tracker = StereoMarkerTracker(
        rig, BASE_T_CAM, marker_id=5, dictionary="DICT_4X4_50", marker_length_m=LENGTH_M
    )
    R_marker = facing_camera(20.0, -15.0, 30.0)
    pos_err, ang_err = [], []
    for k in range(16):
        t = k * 0.05
        left_p = np.array([0.05 * math.sin(2 * math.pi * 0.3 * t), -0.01, 0.48])
        left_T_marker = pose(R_marker, left_p)
        frame_l, frame_r = _frames(rig, left_T_marker, rng)
        est = tracker.observe(frame_l, frame_r, t)
        assert est.status in ("initialised", "updated")
        base_T_marker = BASE_T_CAM @ left_T_marker
        pos_err.append(np.linalg.norm(est.position_m - base_T_marker[:3, 3]))
        q_true = quaternion_from_matrix(base_T_marker[:3, :3])
        assert est.orientation_wxyz is not None
        ang_err.append(
            math.degrees(2 * math.acos(min(1.0, abs(float(est.orientation_wxyz @ q_true)))))
        )
        meas = tracker.last_measurement
        assert meas is not None and meas.epipolar_px < 0.5 and meas.fit_rms_m < 0.001
    assert max(pos_err) < 0.004 and float(np.sqrt(np.mean(np.square(pos_err)))) < 0.002
    assert max(ang_err[3:]) < 3.0  # orientation is smoothed, so give it a few frames


def test_miss_predicts_and_latency_prediction(rig: StereoRig) -> None:
    rng = np.random.default_rng(1)
    tracker = StereoMarkerTracker(rig, marker_id=5, marker_length_m=LENGTH_M)  # left camera frame
    left_T_marker = pose(facing_camera(0, 0, 0), [0.0, 0.0, 0.5])
    frames = _frames(rig, left_T_marker, rng)
    for k in range(5):
        est = tracker.observe(*frames, k * 0.05)
    np.testing.assert_allclose(est.position_m, [0.0, 0.0, 0.5], atol=0.002)
    blank = np.full((480, 640), 110, np.uint8)
    est = tracker.observe(blank, frames[1], 5 * 0.05)  # marker hidden from one camera
    assert est.status == "predicted" and est.valid
    assert tracker.last_measurement is None
    ahead = tracker.predict(5 * 0.05 + 0.1)
    np.testing.assert_allclose(ahead.position_m, [0.0, 0.0, 0.5], atol=0.003)


def test_inconsistent_detection_is_a_miss(rig: StereoRig) -> None:
    """Two different markers with the same id in the two images do not triangulate."""
    rng = np.random.default_rng(2)
    tracker = StereoMarkerTracker(rig, marker_id=5, marker_length_m=LENGTH_M)
    left = _frames(rig, pose(facing_camera(0, 0, 0), [0.06, 0.0, 0.5]), rng)[0]
    right = _frames(rig, pose(facing_camera(0, 0, 0), [0.0, 0.05, 0.5]), rng)[1]
    assert tracker.measure(left, right) is None


def test_constructor_validation(rig: StereoRig) -> None:
    with pytest.raises(ConfigError):
        StereoMarkerTracker(rig, np.eye(3))
    with pytest.raises(ConfigError):
        StereoMarkerTracker(rig, marker_length_m=-0.01)
    base_p = transform_points(BASE_T_CAM, np.zeros(3))
    np.testing.assert_allclose(base_p[0], BASE_T_CAM[:3, 3])


def test_colour_blob_tracker(rig: StereoRig) -> None:
    """The alternative detector: a red ball rendered as a disc in both BGR images."""
    import cv2

    from calibration.perception import StereoBlobTracker

    def frame(uv: np.ndarray) -> np.ndarray:
        big = np.full((480 * 4, 640 * 4, 3), (60, 60, 60), np.uint8)
        cx, cy = ((c + 0.5) * 4 - 0.5 for c in uv)
        cv2.circle(
            big,
            (round(cx * 16), round(cy * 16)),
            8 * 4 * 16,
            (40, 40, 210),
            -1,
            lineType=cv2.LINE_AA,
            shift=4,
        )
        return cv2.resize(big, (640, 480), interpolation=cv2.INTER_AREA)

    tracker = StereoBlobTracker(rig, (170, 120, 80), (10, 255, 255), base_T_cam=BASE_T_CAM)
    for k in range(6):
        left_p = np.array([0.02 + 0.002 * k, -0.01, 0.5])
        uv_l = rig.left.project(left_p[None])[0]
        uv_r = rig.right.project((rig.R @ left_p + rig.T)[None])[0]
        est = tracker.observe(frame(uv_l), frame(uv_r), k * 0.05)
        assert est.status in ("initialised", "updated")
        truth = transform_points(BASE_T_CAM, left_p)[0]
        assert np.linalg.norm(est.position_m - truth) < 0.003
    empty = np.full((480, 640, 3), 60, np.uint8)
    assert tracker.observe(empty, empty, 0.3).status == "predicted"
