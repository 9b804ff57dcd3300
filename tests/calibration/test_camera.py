"""CameraModel geometry and its two file formats (OpenCV FileStorage, ROS camera_info)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from calibration.camera import CameraModel
from calibration.errors import CalibrationFileError, ConfigError
from calibration.triangulate import StereoRig


def test_from_fovy_matches_pinhole_geometry() -> None:
    cam = CameraModel.from_fovy(45.0, 640, 480)
    # a point on the top edge of the field of view projects onto the top row edge (y = -0.5)
    top = np.array([[0.0, -np.tan(np.radians(22.5)), 1.0]])
    np.testing.assert_allclose(cam.project(top), [[319.5, -0.5]], atol=1e-9)
    assert not cam.has_distortion


def test_undistort_inverts_project(rig: StereoRig) -> None:
    cam = rig.left
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-0.3, 0.3, (50, 2)), np.ones(50)]) * 0.8
    uv = cam.project(pts)
    np.testing.assert_allclose(cam.undistort_normalized(uv), pts[:, :2] / pts[:, 2:], atol=1e-7)
    ideal = pts[:, :2] / pts[:, 2:] @ cam.K[:2, :2].T + cam.K[:2, 2]
    np.testing.assert_allclose(cam.undistort_pixels(uv), ideal, atol=1e-4)


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"K": np.eye(3) * 0, "dist": np.zeros(5)}, "not a valid intrinsic matrix"),
        ({"K": np.eye(3), "dist": np.zeros(3)}, "3 distortion coefficients"),
        ({"K": np.full((3, 3), np.nan), "dist": np.zeros(5)}, "non-finite"),
        ({"K": np.eye(2), "dist": np.zeros(5)}, "shape (3, 3)"),
    ],
)
def test_invalid_models_rejected(kwargs: dict, fragment: str) -> None:
    with pytest.raises(ConfigError, match=None) as info:
        CameraModel(image_size=(640, 480), **kwargs)
    assert fragment in str(info.value)


def test_model_is_immutable(rig: StereoRig) -> None:
    with pytest.raises(ValueError):
        rig.left.K[0, 0] = 1.0


def test_filestorage_roundtrip_read_by_opencv(tmp_path: Path, rig: StereoRig) -> None:
    path = rig.left.save(tmp_path / "cam.yaml", {"rms_px": 0.21})
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)  # OpenCV itself reads it
    np.testing.assert_allclose(fs.getNode("camera_matrix").mat(), rig.left.K)
    np.testing.assert_allclose(fs.getNode("distortion_coefficients").mat().ravel(), rig.left.dist)
    assert fs.getNode("image_width").real() == 640
    assert fs.getNode("rms_px").real() == pytest.approx(0.21)
    fs.release()
    back = CameraModel.load(path)
    np.testing.assert_allclose(back.K, rig.left.K)
    np.testing.assert_allclose(back.dist, rig.left.dist)
    assert back.image_size == (640, 480) and back.name == "left"


def test_ros_camera_info_is_plain_yaml(tmp_path: Path, rig: StereoRig) -> None:
    rect = rig.rectification
    text = rig.right.ros_yaml(rect.R2, rect.P2)
    doc = yaml.safe_load(text)
    assert doc["image_width"] == 640 and doc["image_height"] == 480
    assert doc["camera_name"] == "right"
    assert doc["distortion_model"] == "plumb_bob"
    assert doc["camera_matrix"]["rows"] == 3 and doc["camera_matrix"]["cols"] == 3
    np.testing.assert_allclose(np.reshape(doc["camera_matrix"]["data"], (3, 3)), rig.right.K)
    np.testing.assert_allclose(np.reshape(doc["projection_matrix"]["data"], (3, 4)), rect.P2)
    np.testing.assert_allclose(np.reshape(doc["rectification_matrix"]["data"], (3, 3)), rect.R2)
    path = tmp_path / "right_camera_info.yaml"
    path.write_text(text)
    back = CameraModel.load(path)
    np.testing.assert_allclose(back.K, rig.right.K)
    np.testing.assert_allclose(back.dist, rig.right.dist)


def test_rational_model_is_named_for_ros() -> None:
    cam = CameraModel(K=np.diag([500.0, 500.0, 1.0]), dist=np.zeros(8), image_size=(64, 48))
    assert yaml.safe_load(cam.ros_yaml())["distortion_model"] == "rational_polynomial"


@pytest.mark.parametrize(
    ("content", "fragment"),
    [
        ("garbage: [1, 2", "not a valid OpenCV YAML file"),
        ("%YAML:1.0\n---\nimage_width: 640\n", "missing matrix 'camera_matrix'"),
    ],
)
def test_bad_files_name_the_file(tmp_path: Path, content: str, fragment: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(content)
    with pytest.raises(CalibrationFileError) as info:
        CameraModel.load(path)
    assert fragment in str(info.value) and str(path) in str(info.value)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(CalibrationFileError, match="not found"):
        CameraModel.load(tmp_path / "nope.yaml")
