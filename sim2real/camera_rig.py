"""The stereo camera rig the twin carries: where each camera stands, what it looks at, its
intrinsics.

Apart from the MJCF (``sim2real.twin_mjcf``) because the deploy runtime, placement and the
calibration side need the rig's geometry without MuJoCo: this module imports numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sim2real.errors import ConfigError, UnknownNameError


@dataclass(frozen=True)
class CameraSpec:
    """A pinhole camera of the rig: pose in the base frame and intrinsics (vertical fov)."""

    name: str
    base_p_cam_m: tuple[float, float, float]
    look_at_m: tuple[float, float, float]
    fovy_deg: float = 45.0
    width_px: int = 640
    height_px: int = 480

    def __post_init__(self) -> None:
        if not 5.0 < self.fovy_deg < 170.0:
            raise ConfigError(f"camera {self.name}: fovy_deg {self.fovy_deg} not in (5, 170)")
        if self.width_px <= 0 or self.height_px <= 0:
            raise ConfigError(
                f"camera {self.name}: image size {self.width_px}x{self.height_px} must be positive"
            )
        if np.allclose(self.base_p_cam_m, self.look_at_m):
            raise ConfigError(f"camera {self.name}: position equals look_at {self.look_at_m}")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels: MuJoCo's fovy is the vertical field of view."""
        return 0.5 * self.height_px / math.tan(math.radians(self.fovy_deg) / 2)

    def intrinsics(self) -> np.ndarray:
        """K (3, 3) of the rendered image (square pixels, principal point at the centre)."""
        f = self.focal_px
        return np.array(
            [[f, 0.0, (self.width_px - 1) / 2], [0.0, f, (self.height_px - 1) / 2], [0, 0, 1.0]]
        )

    def base_R_cam_mujoco(self) -> np.ndarray:
        """Rotation (3, 3) whose columns are the MuJoCo camera axes (x right, y up, -z forward)."""
        fwd = np.subtract(self.look_at_m, self.base_p_cam_m)
        fwd = fwd / np.linalg.norm(fwd)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        if np.linalg.norm(right) < 1e-9:
            raise ConfigError(f"camera {self.name}: looking straight up/down is not supported")
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        return np.stack([right, up, -fwd], axis=1)

    def base_T_cam(self) -> np.ndarray:
        """Pose (4, 4) of the OpenCV camera frame (x right, y down, z forward) in the base frame."""
        R_mj = self.base_R_cam_mujoco()
        T = np.eye(4)
        T[:3, :3] = R_mj @ np.diag([1.0, -1.0, -1.0])
        T[:3, 3] = self.base_p_cam_m
        return T


def _stereo_pair(
    centre_m: tuple[float, float, float],
    look_at_m: tuple[float, float, float],
    baseline_m: float,
    fovy_deg: float,
) -> tuple[CameraSpec, CameraSpec]:
    fwd = np.subtract(look_at_m, centre_m)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    offset = right * baseline_m / 2
    left_p = tuple(float(v) for v in np.subtract(centre_m, offset))
    right_p = tuple(float(v) for v in np.add(centre_m, offset))
    # Parallel optical axes: each camera looks at the look-at point shifted by its own offset.
    left_look = tuple(float(v) for v in np.subtract(look_at_m, offset))
    right_look = tuple(float(v) for v in np.add(look_at_m, offset))
    return (
        CameraSpec("cam_left", left_p, left_look, fovy_deg),  # type: ignore[arg-type]
        CameraSpec("cam_right", right_p, right_look, fovy_deg),  # type: ignore[arg-type]
    )


@dataclass(frozen=True)
class RigSpec:
    """Two cameras forming a stereo rig in front of the arm (baseline along the camera x axis)."""

    centre_m: tuple[float, float, float] = (0.6, 0.0, 0.45)
    look_at_m: tuple[float, float, float] = (0.08, 0.0, 0.06)
    baseline_m: float = 0.1
    fovy_deg: float = 55.0
    cameras: tuple[CameraSpec, ...] = field(init=False)

    def __post_init__(self) -> None:
        if not 0.005 <= self.baseline_m <= 1.0:
            raise ConfigError(f"rig baseline_m {self.baseline_m} not in [0.005, 1.0]")
        object.__setattr__(
            self,
            "cameras",
            _stereo_pair(self.centre_m, self.look_at_m, self.baseline_m, self.fovy_deg),
        )

    def camera(self, name: str) -> CameraSpec:
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise UnknownNameError("camera", name, [c.name for c in self.cameras])
