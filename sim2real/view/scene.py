"""The geometry the viewer draws, without Rerun: the arm as a line strip from the spec's
kinematics, the two cameras' models for overlays, and the markers found in a frame.

The strip runs base -> shoulder -> elbow -> wrist -> tool (forward, then down: the tool offset of
``LinkSpec``), so its elbow is ``ArmSpec.elbow_position`` and its end
``ArmSpec.forward_kinematics`` (tested). Cameras are the mock rig's by default (the ``sim`` and
``mock`` backends render it, and ``evaluate`` records it) or a real rig's calibration and
registration; a camera is scaled to the frames it is drawn on (datasets keep 320x240).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hardware.spec import ArmSpec
from sim2real import scene_names as names

# Which marker an id is, on the mock rig (``scene_names``): labels drawn beside each detection.
MARKER_NAMES: dict[int, str] = {
    names.EE_MARKER_ID: "wrist",
    names.TARGET_MARKER_ID: "target",
    **{i: "cube" for i in names.MARKER_CUBE.face_ids},
    names.SEAM_MARKERS.start_id: "seam_start",
    names.SEAM_MARKERS.end_id: "seam_end",
}


def arm_points_m(spec: ArmSpec, q_rad: np.ndarray) -> np.ndarray:
    """(6, 3) base-frame points of the arm at joint angles ``q_rad`` (the first three entries;
    a gripper entry is ignored): base, shoulder, elbow, wrist, tool offset forward, tool."""
    q = np.asarray(q_rad, dtype=float)
    if not np.all(np.isfinite(q[:3])):
        return np.full((6, 3), np.nan)
    L = spec.links
    yaw = spec.joints[0].sign * q[0]
    a1 = spec.joints[1].sign * q[1]
    a12 = a1 + spec.joints[2].sign * q[2]
    r_elbow, z_elbow = L.upper_arm_m * math.sin(a1), L.base_height_m + L.upper_arm_m * math.cos(a1)
    r_wrist = r_elbow + L.forearm_m * math.cos(a12)
    z_wrist = z_elbow - L.forearm_m * math.sin(a12)
    rz = [
        (0.0, 0.0),
        (0.0, L.base_height_m),
        (r_elbow, z_elbow),
        (r_wrist, z_wrist),
        (r_wrist + L.tool_forward_m, z_wrist),
        (r_wrist + L.tool_forward_m, z_wrist - L.tool_down_m),
    ]
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[r * c, r * s, z] for r, z in rz])


@dataclass(frozen=True)
class ViewCamera:
    """One camera: intrinsics at ``size_wh``, distortion, and its OpenCV frame in the base."""

    name: str
    K: np.ndarray  # (3, 3)
    dist: np.ndarray  # OpenCV coefficients
    size_wh: tuple[int, int]
    base_T_cam: np.ndarray  # noqa: N815 - (4, 4): frame names are part of the name

    def scaled(self, size_wh: tuple[int, int]) -> ViewCamera:
        """The same camera for frames resized to ``size_wh`` (pixel centres kept)."""
        if tuple(size_wh) == tuple(self.size_wh):
            return self
        sx, sy = size_wh[0] / self.size_wh[0], size_wh[1] / self.size_wh[1]
        K = self.K.copy()
        K[0, 0], K[0, 2] = K[0, 0] * sx, (K[0, 2] + 0.5) * sx - 0.5
        K[1, 1], K[1, 2] = K[1, 1] * sy, (K[1, 2] + 0.5) * sy - 0.5
        return dataclasses.replace(self, K=K, size_wh=(int(size_wh[0]), int(size_wh[1])))

    def project(self, base_p_m: np.ndarray) -> np.ndarray:
        """(N, 3) base-frame points -> (N, 2) pixels; NaN for a missing point or one behind."""
        p = np.asarray(base_p_m, dtype=float).reshape(-1, 3)
        cam_T_base = np.linalg.inv(self.base_T_cam)
        cam_p = p @ cam_T_base[:3, :3].T + cam_T_base[:3, 3]
        out = np.full((len(p), 2), np.nan)
        ok = np.all(np.isfinite(cam_p), axis=1) & (cam_p[:, 2] > 1e-6)
        if ok.any():
            import cv2

            uv, _ = cv2.projectPoints(cam_p[ok], np.zeros(3), np.zeros(3), self.K, self.dist)
            out[ok] = uv.reshape(-1, 2)
        return out


def mock_rig_cameras() -> tuple[ViewCamera, ViewCamera]:
    """The rig the ``sim`` and ``mock`` backends and ``evaluate`` render (imports MuJoCo)."""
    from sim2real.model import RigSpec

    cams = RigSpec().cameras
    return tuple(  # type: ignore[return-value]
        ViewCamera(c.name, c.intrinsics(), np.zeros(5), (c.width_px, c.height_px), c.base_T_cam())
        for c in cams
    )


def calibrated_cameras(calibration: Path, registration: Path) -> tuple[ViewCamera, ViewCamera]:
    """A real rig: ``calibrate stereo``'s file and ``calibrate register``'s ``base_T_cam``."""
    from calibration.registration import load_base_T_cam
    from calibration.triangulate import StereoRig

    rig = StereoRig.load(calibration)
    base_T_left = load_base_T_cam(registration)
    base_T_right = base_T_left @ np.linalg.inv(rig.right_T_left)
    return (
        _from_model(rig.left, "cam_left", base_T_left),
        _from_model(rig.right, "cam_right", base_T_right),
    )


def _from_model(model: Any, name: str, base_T_cam: np.ndarray) -> ViewCamera:
    w, h = model.image_size
    return ViewCamera(name, np.array(model.K), np.array(model.dist), (int(w), int(h)), base_T_cam)


@dataclass(frozen=True)
class MarkerSighting:
    id: int
    corners_px: np.ndarray  # (4, 2)

    @property
    def label(self) -> str:
        return f"{self.id} {MARKER_NAMES.get(self.id, '?')}"


class MarkerFinder:
    """The project's ArUco detector (``calibration.markers``) on RGB frames."""

    def __init__(self, dictionary: str = names.MARKER_DICTIONARY) -> None:
        from calibration.markers import ArucoMarkerDetector

        self._detector = ArucoMarkerDetector(dictionary)

    def find(self, rgb: np.ndarray) -> list[MarkerSighting]:
        found = self._detector.detect(np.ascontiguousarray(rgb[:, :, ::-1]))
        return [MarkerSighting(m.id, m.corners_px) for m in found]
