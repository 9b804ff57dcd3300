"""``StereoRig``: two calibrated cameras and their relative pose; triangulation and marker pose.

Convention (OpenCV's ``stereoCalibrate``): a point ``left_p`` in the left camera frame is
``right_p = R · left_p + T`` in the right one, so ``right_T_left = [R | T]``. Camera frames are
OpenCV's: x right, y down, z forward. Units of T are the board's (metres by convention).

``cv2.triangulatePoints`` applies no distortion, so points are undistorted to normalised
coordinates first and triangulated with P_left = [I | 0], P_right = [R | T].
"""

from __future__ import annotations

import functools
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from calibration.camera import CameraModel, fs_dumps, fs_loads, fs_mat, fs_real, read_text
from calibration.errors import CalibrationFileError, ConfigError
from calibration.registration import umeyama
from s2r_common.atomic import atomic_write_text

# OpenGL/MuJoCo cameras look along −z with y up; OpenCV's along +z with y down.
GL_FROM_CV = np.diag([1.0, -1.0, -1.0])


def cv_pose_from_gl(world_T_cam_gl: np.ndarray) -> np.ndarray:
    """A camera pose in OpenGL/MuJoCo convention → the same camera in OpenCV convention."""
    out = np.array(world_T_cam_gl, np.float64, copy=True)
    out[:3, :3] = out[:3, :3] @ GL_FROM_CV
    return out


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


@dataclass(frozen=True)
class Rectification:
    """``cv2.stereoRectify`` output: rotations R1/R2, projections P1/P2 (3×4), reprojection Q."""

    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray


@dataclass(frozen=True, eq=False)
class StereoRig:
    """Two cameras and ``right_T_left`` = [R | T]. Build it from a calibration or directly."""

    left: CameraModel
    right: CameraModel
    R: np.ndarray
    T: np.ndarray
    _P_left: np.ndarray = field(init=False, repr=False)
    _P_right: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        R = np.array(self.R, np.float64, copy=True)
        T = np.array(self.T, np.float64, copy=True).ravel()
        if R.shape != (3, 3) or T.shape != (3,):
            raise ConfigError(f"R must be 3x3 and T length 3, got {R.shape} and {T.shape}")
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(T))):
            raise ConfigError("R or T contains non-finite values")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ConfigError(f"R is not a rotation matrix: {R.tolist()}")
        if np.linalg.norm(T) <= 0:
            raise ConfigError("T is zero: the two cameras are at the same place")
        R.setflags(write=False)
        T.setflags(write=False)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "T", T)
        P_left = np.hstack([np.eye(3), np.zeros((3, 1))])
        P_right = np.hstack([R, T.reshape(3, 1)])
        object.__setattr__(self, "_P_left", P_left)
        object.__setattr__(self, "_P_right", P_right)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_poses(
        cls,
        left: CameraModel,
        right: CameraModel,
        world_T_left: np.ndarray,
        world_T_right: np.ndarray,
    ) -> StereoRig:
        """From two camera poses in any common frame (OpenCV camera convention)."""
        right_T_left = np.linalg.inv(world_T_right) @ world_T_left
        return cls(left, right, right_T_left[:3, :3], right_T_left[:3, 3])

    # ------------------------------------------------------------------ geometry
    @property
    def baseline(self) -> float:
        """Distance between the optical centres, in T's units."""
        return float(np.linalg.norm(self.T))

    @property
    def right_T_left(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R, self.T
        return T

    @functools.cached_property
    def E(self) -> np.ndarray:
        """Essential matrix: x_rᵀ E x_l = 0 for normalised coordinates."""
        return _skew(self.T) @ self.R

    @functools.cached_property
    def F(self) -> np.ndarray:
        """Fundamental matrix for *undistorted* pixel coordinates."""
        F = np.linalg.inv(self.right.K).T @ self.E @ np.linalg.inv(self.left.K)
        return F / F[2, 2] if abs(F[2, 2]) > 1e-12 else F

    @functools.cached_property
    def rectification(self) -> Rectification:
        """Rectifying rotations and projections (``alpha = 0``: only valid pixels)."""
        if self.left.image_size != self.right.image_size:
            raise ConfigError(
                f"rectification needs equal image sizes, got {self.left.image_size} and "
                f"{self.right.image_size}"
            )
        R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
            self.left.K, self.left.dist, self.right.K, self.right.dist,
            self.left.image_size, self.R, self.T, flags=cv2.CALIB_ZERO_DISPARITY, alpha=0,
        )  # fmt: skip
        return Rectification(R1, R2, P1, P2, Q)

    def triangulate(self, uv_left: np.ndarray, uv_right: np.ndarray) -> np.ndarray:
        """Matched pixel points (N,2) in both images → points (N,3) in the left camera frame."""
        xl = self.left.undistort_normalized(uv_left)
        xr = self.right.undistort_normalized(uv_right)
        if len(xl) != len(xr):
            raise ValueError(f"{len(xl)} left points but {len(xr)} right points")
        hom = cv2.triangulatePoints(self._P_left, self._P_right, xl.T.copy(), xr.T.copy())
        return (hom[:3] / hom[3]).T

    def reprojection_errors_px(
        self, left_p: np.ndarray, uv_left: np.ndarray, uv_right: np.ndarray
    ) -> np.ndarray:
        """Per point (N,), the larger of the two images' reprojection errors in px."""
        e_l = np.linalg.norm(self.left.project(left_p) - np.reshape(uv_left, (-1, 2)), axis=1)
        right_p = left_p @ self.R.T + self.T
        e_r = np.linalg.norm(self.right.project(right_p) - np.reshape(uv_right, (-1, 2)), axis=1)
        return np.maximum(e_l, e_r)

    def epipolar_errors_px(self, uv_left: np.ndarray, uv_right: np.ndarray) -> np.ndarray:
        """Distance (N,) of each undistorted right point to the epipolar line of its left match."""
        ul = self.left.undistort_pixels(uv_left)
        ur = self.right.undistort_pixels(uv_right)
        hl = np.column_stack([ul, np.ones(len(ul))])
        hr = np.column_stack([ur, np.ones(len(ur))])
        lines = hl @ self.F.T
        return np.abs(np.sum(lines * hr, axis=1)) / np.linalg.norm(lines[:, :2], axis=1)

    # ------------------------------------------------------------------ file io
    def fs_entries(self) -> dict[str, Any]:
        rect = self.rectification if self.left.image_size == self.right.image_size else None
        entries: dict[str, Any] = {
            "left_name": self.left.name,
            "right_name": self.right.name,
            "image_width1": self.left.image_size[0],
            "image_height1": self.left.image_size[1],
            "image_width2": self.right.image_size[0],
            "image_height2": self.right.image_size[1],
            "K1": self.left.K,
            "D1": self.left.dist.reshape(1, -1),
            "K2": self.right.K,
            "D2": self.right.dist.reshape(1, -1),
            "R": self.R,
            "T": self.T.reshape(3, 1),
            "E": self.E,
            "F": self.F,
            "baseline": self.baseline,
        }
        if rect is not None:
            entries.update(R1=rect.R1, R2=rect.R2, P1=rect.P1, P2=rect.P2, Q=rect.Q)
        return entries

    def save(self, path: str | os.PathLike[str], extra: Mapping[str, Any] | None = None) -> Path:
        """One stereo calibration file (OpenCV FileStorage YAML), written atomically."""
        entries = self.fs_entries()
        if extra:
            entries.update(extra)
        return atomic_write_text(path, fs_dumps(entries))

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> StereoRig:
        """Read a file written by :meth:`save` (``sim2real calibrate stereo`` writes one)."""
        src = str(path)
        fs = fs_loads(read_text(path), src)

        def camera(i: int, default: str) -> CameraModel:
            node = fs.getNode(f"{default}_name")
            size = (
                int(fs_real(fs, f"image_width{i}", src)),
                int(fs_real(fs, f"image_height{i}", src)),
            )
            try:
                return CameraModel(
                    K=fs_mat(fs, f"K{i}", src),
                    dist=fs_mat(fs, f"D{i}", src).ravel(),
                    image_size=size,
                    name=node.string() if not node.empty() else default,
                )
            except ConfigError as exc:
                raise CalibrationFileError(f"{src}: {exc}") from exc

        left, right = camera(1, "left"), camera(2, "right")
        try:
            return cls(left, right, fs_mat(fs, "R", src), fs_mat(fs, "T", src).ravel())
        except ConfigError as exc:
            raise CalibrationFileError(f"{src}: {exc}") from exc


def fit_marker_pose(
    cam_corners: np.ndarray, marker_corners_m: np.ndarray
) -> tuple[np.ndarray, float]:
    """6-DOF pose ``cam_T_marker`` (4×4) of a square from its four triangulated corners.

    ``marker_corners_m`` (4,3) are the corners in the marker frame. Returns the pose and the RMS
    distance (m) between the fitted model and the triangulated corners (a shape check).
    """
    R, t, _ = umeyama(marker_corners_m, cam_corners)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    fitted = marker_corners_m @ R.T + t
    rms = float(np.sqrt(np.mean(np.sum((fitted - cam_corners) ** 2, axis=1))))
    return T, rms


def quaternion_from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w ≥ 0, of a rotation matrix (Shepperd's method)."""
    m = np.asarray(R, np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = np.array([0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s,
                      (m[1, 0] - m[0, 1]) / s])  # fmt: skip
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = np.array([(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s,
                      (m[0, 2] + m[2, 0]) / s])  # fmt: skip
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = np.array([(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s,
                      (m[1, 2] + m[2, 1]) / s])  # fmt: skip
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = np.array([(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s,
                      (m[1, 2] + m[2, 1]) / s, 0.25 * s])  # fmt: skip
    q /= np.linalg.norm(q)
    return np.asarray(q if q[0] >= 0 else -q)


def matrix_from_quaternion(q_wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrix of a (not necessarily unit) quaternion (w, x, y, z)."""
    w, x, y, z = np.asarray(q_wxyz, np.float64) / np.linalg.norm(q_wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
