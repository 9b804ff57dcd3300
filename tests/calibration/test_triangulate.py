"""StereoRig: triangulation with distortion, epipolar geometry, file round trip, marker pose."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.camera import CameraModel
from calibration.errors import CalibrationFileError, ConfigError
from calibration.markers import marker_corners
from calibration.synthetic import facing_camera, pose, rotation
from calibration.triangulate import (
    StereoRig,
    cv_pose_from_gl,
    fit_marker_pose,
    matrix_from_quaternion,
    quaternion_from_matrix,
)


def _points(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.15, 0.15, (n, 2)), rng.uniform(0.3, 0.9, n)])


def test_triangulate_exact_with_distortion(rig: StereoRig) -> None:
    """Distorted pixels in, the true 3-D points out: undistortion happens before DLT."""
    left_p = _points(40)
    uv_l = rig.left.project(left_p)
    uv_r = rig.right.project(left_p @ rig.R.T + rig.T)
    np.testing.assert_allclose(rig.triangulate(uv_l, uv_r), left_p, atol=1e-6)
    assert rig.reprojection_errors_px(left_p, uv_l, uv_r).max() < 1e-6
    assert rig.epipolar_errors_px(uv_l, uv_r).max() < 1e-4  # undistortPoints iterates


def test_triangulate_skipping_undistortion_would_be_wrong(rig: StereoRig) -> None:
    """The trap this guards against: cv2.triangulatePoints on raw distorted pixels."""
    left_p = _points(40)
    uv_l = rig.left.project(left_p)
    uv_r = rig.right.project(left_p @ rig.R.T + rig.T)
    P1 = rig.left.K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = rig.right.K @ np.hstack([rig.R, rig.T.reshape(3, 1)])
    raw = cv2.triangulatePoints(P1, P2, uv_l.T.copy(), uv_r.T.copy())
    naive = (raw[:3] / raw[3]).T
    assert np.abs(naive - left_p).max() > 0.003  # millimetres off near the edges


def test_epipolar_error_measures_vertical_offset(rig: StereoRig) -> None:
    left_p = _points(10)
    uv_l = rig.left.project(left_p)
    uv_r = rig.right.project(left_p @ rig.R.T + rig.T) + np.array([0.0, 2.0])
    err = rig.epipolar_errors_px(uv_l, uv_r)
    assert np.all((err > 1.8) & (err < 2.3))  # near-horizontal lines; undistortion stretches


def test_save_load_roundtrip(tmp_path: Path, rig: StereoRig) -> None:
    path = rig.save(tmp_path / "stereo.yaml", {"rms_px": 0.1})
    back = StereoRig.load(path)
    np.testing.assert_allclose(back.R, rig.R)
    np.testing.assert_allclose(back.T, rig.T)
    np.testing.assert_allclose(back.left.K, rig.left.K)
    np.testing.assert_allclose(back.right.dist, rig.right.dist)
    assert (back.left.name, back.right.name) == ("left", "right")
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    np.testing.assert_allclose(fs.getNode("F").mat(), rig.F)
    np.testing.assert_allclose(fs.getNode("P2").mat(), rig.rectification.P2)
    fs.release()


def test_load_rejects_bad_rotation(tmp_path: Path, rig: StereoRig) -> None:
    from calibration.camera import fs_dumps

    entries = rig.fs_entries()
    entries["R"] = np.eye(3) * 2
    (tmp_path / "bad.yaml").write_text(fs_dumps(entries))
    with pytest.raises(CalibrationFileError, match="not a rotation"):
        StereoRig.load(tmp_path / "bad.yaml")


def test_direct_construction_for_simulated_cameras() -> None:
    """MuJoCo cameras (−z forward, y up) → OpenCV rig, from poses in a world frame."""
    cam = CameraModel.from_fovy(45.0, 640, 480)
    world_T_left_gl = pose(rotation(0, 0, 0), [0.0, 0.0, 1.0])  # looks down −z at the origin
    world_T_right_gl = pose(rotation(0, 0, 0), [0.1, 0.0, 1.0])
    rig = StereoRig.from_poses(
        cam, cam, cv_pose_from_gl(world_T_left_gl), cv_pose_from_gl(world_T_right_gl)
    )
    assert rig.baseline == pytest.approx(0.1)
    np.testing.assert_allclose(rig.T, [-0.1, 0.0, 0.0], atol=1e-12)
    # the world origin is 1 m in front of the left camera, on its optical axis
    world_p = np.array([[0.0, 0.0, 0.0]])
    left_T_world = np.linalg.inv(cv_pose_from_gl(world_T_left_gl))
    left_p = world_p @ left_T_world[:3, :3].T + left_T_world[:3, 3]
    np.testing.assert_allclose(left_p, [[0.0, 0.0, 1.0]], atol=1e-12)
    uv_l = cam.project(left_p)
    uv_r = cam.project(left_p @ rig.R.T + rig.T)
    np.testing.assert_allclose(rig.triangulate(uv_l, uv_r), left_p, atol=1e-9)


def test_invalid_rig() -> None:
    cam = CameraModel.from_fovy(45.0, 64, 48)
    with pytest.raises(ConfigError, match="T is zero"):
        StereoRig(cam, cam, np.eye(3), np.zeros(3))
    with pytest.raises(ConfigError, match="not a rotation"):
        StereoRig(cam, cam, np.diag([1.0, 1.0, -1.0]), [0.1, 0, 0])


def test_marker_pose_fit() -> None:
    cam_T_marker = pose(facing_camera(25, -10, 40), [0.05, -0.02, 0.5])
    model = marker_corners(0.04)
    corners = model @ cam_T_marker[:3, :3].T + cam_T_marker[:3, 3]
    fitted, rms = fit_marker_pose(corners, model)
    np.testing.assert_allclose(fitted, cam_T_marker, atol=1e-9)
    assert rms < 1e-9


def test_quaternion_roundtrip() -> None:
    rng = np.random.default_rng(3)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q = q if q[0] >= 0 else -q
        np.testing.assert_allclose(quaternion_from_matrix(matrix_from_quaternion(q)), q, atol=1e-9)
    for angles in ((180, 0, 0), (0, 180, 0), (0, 0, 180)):
        R = rotation(*angles)
        np.testing.assert_allclose(matrix_from_quaternion(quaternion_from_matrix(R)), R, atol=1e-9)
