"""Virtual cameras: the stereo rig rendered in MuJoCo, so detection, triangulation and the Kalman
filter run on real images in the mock-hardware loop.

The scene is posed from outside (the emulator's true servo angles, the target's pose) and both
cameras render the same instant. Frames are BGR, as ``cv2.VideoCapture`` delivers them, and the
rig's exact pinhole intrinsics/extrinsics are available as a ``calibration.StereoRig``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import mujoco
import numpy as np

from calibration.camera import CameraModel
from calibration.triangulate import StereoRig
from hardware.spec import ArmSpec
from sim2real import model as names
from sim2real.camera_rig import RigSpec
from sim2real.deploy.marker_textures import install_marker_textures, marker_image
from sim2real.rendering import FastRenderer
from sim2real.twin import ArmTwin
from sim2real.twin_mjcf import build_model

__all__ = [
    "StereoFrames",
    "VirtualStereoCameras",
    "install_marker_textures",
    "marker_image",
    "stereo_rig_of",
    "target_quat_facing",
]


def stereo_rig_of(rig: RigSpec) -> tuple[StereoRig, np.ndarray]:
    """The rig's exact calibration (zero distortion) and ``base_T_left`` (OpenCV camera frame)."""
    left_spec, right_spec = rig.cameras
    models = [
        CameraModel(c.intrinsics(), np.zeros(5), (c.width_px, c.height_px), name=c.name)
        for c in rig.cameras
    ]
    base_T_left, base_T_right = left_spec.base_T_cam(), right_spec.base_T_cam()
    return StereoRig.from_poses(models[0], models[1], base_T_left, base_T_right), base_T_left


def target_quat_facing(rig: RigSpec, position_m: np.ndarray) -> np.ndarray:
    """(w, x, y, z) orientation whose +z (the plate's face) points at the rig centre."""
    z = np.subtract(rig.centre_m, position_m)
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 0.0, 1.0], z)
    x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-9 else np.array([1.0, 0.0, 0.0])
    y = np.cross(z, x)
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.stack([x, y, z], axis=1).ravel())
    return q


@dataclass(frozen=True)
class StereoFrames:
    left_bgr: np.ndarray  # (H, W, 3) uint8
    right_bgr: np.ndarray
    timestamp_s: float


class VirtualStereoCameras:
    """Two rendered cameras of one posed scene; ``read()`` renders both at the same instant."""

    def __init__(self, spec: ArmSpec, rig: RigSpec | None = None, scene: str = "reach") -> None:
        self.rig = rig or RigSpec()
        self.model = build_model(spec, scene, self.rig, markers=True)
        install_marker_textures(self.model)
        self.data = mujoco.MjData(self.model)
        self.twin = ArmTwin(self.model, spec)
        cam = self.rig.cameras[0]
        self.width, self.height = cam.width_px, cam.height_px
        self._renderer: FastRenderer | None = None
        self._target_mocap = int(self.model.body_mocapid[self.model.body(names.TARGET_BODY).id])

    def pose(self, actuators_rad: np.ndarray, target_m: np.ndarray | None) -> None:
        """Pose the arm (n_actuators,) and the target plate; kinematics only, no dynamics."""
        q = np.asarray(actuators_rad, dtype=float)
        grip = float(q[-1]) if self.twin.has_gripper and len(q) > self.twin.n_joints else None
        self.twin.set_pose(self.data, q, grip)
        if target_m is not None:
            self.data.mocap_pos[self._target_mocap] = target_m
            self.data.mocap_quat[self._target_mocap] = target_quat_facing(self.rig, target_m)
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)  # cameras and lights follow the bodies

    def tool_position(self) -> np.ndarray:
        return self.twin.tool_position(self.data).copy()

    def ee_marker_pose(self) -> np.ndarray:
        """``base_T_marker`` (4, 4) of the wrist marker plate (geom frame, +z out of the face)."""
        g = self.model.geom(names.EE_MARKER_GEOM).id
        T = np.eye(4)
        T[:3, :3] = self.data.geom_xmat[g].reshape(3, 3)
        T[:3, 3] = self.data.geom_xpos[g]
        return T

    def read(self) -> StereoFrames:
        if self._renderer is None:
            self._renderer = FastRenderer(self.model, self.width, self.height)
        left = self._renderer.render(self.data, "cam_left")[:, :, ::-1].copy()
        right = self._renderer.render(self.data, "cam_right")[:, :, ::-1].copy()
        return StereoFrames(left, right, time.monotonic())

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
