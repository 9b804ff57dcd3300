"""Where the deploy loop's end-effector and target estimates come from.

``StereoPerception`` is the real pipeline, ``calibration.perception.StereoMarkerTracker`` per
marker: two frames → ArUco detection (sub-pixel corners, ROI around the last detection) →
undistort + triangulate the four corners → pose fit → base frame → Kalman tracker. The target is the target plate's centre; the tool is the wrist plate's centre plus
the plate-to-tool offset turned by the base yaw joint reading: the parallel linkage keeps the
gripper level, so yaw is the only rotation, and the servo reads yaw more precisely than a 3 cm
marker seen at 40° can. ``OraclePerception`` is ground truth (the ``sim`` backend without cameras).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from calibration.errors import CalibrationError
from calibration.kalman import TrackerConfig
from calibration.perception import StereoMarkerTracker
from calibration.triangulate import StereoRig
from hardware.arm import ArmState
from hardware.spec import ArmSpec
from sim2real import model as names
from sim2real.deploy.loop import Percept


@dataclass(frozen=True)
class MarkerLayout:
    """Marker ids, sizes and the wrist plate's offset to the tool, in the plate frame."""

    dictionary: str = names.MARKER_DICTIONARY
    target_id: int = names.TARGET_MARKER_ID
    target_size_m: float = names.TARGET_MARKER_SIZE_M
    ee_id: int = names.EE_MARKER_ID
    ee_size_m: float = names.EE_MARKER_SIZE_M
    ee_marker_p_tool_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def for_spec(cls, spec: ArmSpec) -> MarkerLayout:
        """The layout the MJCF twin uses: plate on a riser on top of the wrist link."""
        mx, my, mz = names.EE_MARKER_POS_M
        L = spec.links
        return cls(ee_marker_p_tool_m=(L.tool_forward_m - mx, -my, -L.tool_down_m - mz))


class StereoFrameSource:
    """Anything that delivers a time-aligned pair of BGR frames (virtual or two real cameras)."""

    def read_pair(self) -> tuple[np.ndarray, np.ndarray, float]:
        raise NotImplementedError

    def close(self) -> None:
        """Release the cameras."""


class StereoPerception:
    """Two ``calibration.perception.StereoMarkerTracker`` (target plate, wrist plate) on the same
    frame pair, plus the level-gripper offset from the wrist plate to the tool."""

    def __init__(
        self,
        frames: StereoFrameSource,
        rig: StereoRig,
        base_T_left: np.ndarray,
        spec: ArmSpec,
        layout: MarkerLayout | None = None,
        tracker: TrackerConfig | None = None,
        yaw_sign: float = 1.0,
    ) -> None:
        self.frames, self.rig, self.spec = frames, rig, spec
        self.layout = layout or MarkerLayout.for_spec(spec)
        self.base_T_left = np.asarray(base_T_left, dtype=float)
        cfg = tracker or TrackerConfig()
        # The target stands still for an episode: a quiet model that coasts through occlusion
        # (the gripper covers the plate exactly when it arrives).
        self._target_cfg = replace(
            cfg,
            model="cv",
            manoeuvre_std=None,
            process_std=0.001,
            init_velocity_std_mps=0.001,
            max_coast_s=3600.0,
        )
        # The wrist plate moves fast and can turn away: coast at most two periods, then fall
        # back to forward kinematics corrected by the last camera-vs-FK offset.
        self._ee_cfg = replace(cfg, max_coast_s=min(cfg.max_coast_s, 0.1))
        self._offset = np.asarray(self.layout.ee_marker_p_tool_m, dtype=float)
        self._yaw_sign = spec.joints[0].sign * yaw_sign
        self.last_frames: tuple[np.ndarray, np.ndarray] | None = None
        self.detections = {"target": 0, "ee": 0, "periods": 0, "fk_fallback": 0}
        self.reset()

    def _tracker(self, marker_id: int, size_m: float, cfg: TrackerConfig) -> StereoMarkerTracker:
        return StereoMarkerTracker(
            self.rig,
            base_T_cam=self.base_T_left,
            marker_id=marker_id,
            dictionary=self.layout.dictionary,
            marker_length_m=size_m,
            tracker=cfg,
        )

    def reset(self) -> None:
        lay = self.layout
        self.target = self._tracker(lay.target_id, lay.target_size_m, self._target_cfg)
        self.ee = self._tracker(lay.ee_id, lay.ee_size_m, self._ee_cfg)
        self._fk_bias = np.zeros(3)

    def _check_size(self, left_img: np.ndarray, right_img: np.ndarray) -> None:
        """The calibration must be for the resolution the cameras deliver."""
        for name, img, cam in (
            ("left", left_img, self.rig.left),
            ("right", right_img, self.rig.right),
        ):
            size = (img.shape[1], img.shape[0])
            if size != cam.image_size:
                raise CalibrationError(
                    f"the {name} camera delivers {size[0]}x{size[1]} frames but the stereo "
                    f"calibration is for {cam.image_size[0]}x{cam.image_size[1]}: "
                    "recalibrate at this resolution or set the camera to it"
                )

    def perceive(self, state: ArmState, timestamp_s: float) -> Percept:
        left_img, right_img, t = self.frames.read_pair()
        if self.last_frames is None:
            self._check_size(left_img, right_img)
        self.last_frames = (left_img, right_img)
        self.detections["periods"] += 1
        target = self.target.observe(left_img, right_img, t)
        plate = self.ee.observe(left_img, right_img, t)
        seen_ee = self.ee.last_measurement is not None
        self.detections["target"] += int(self.target.last_measurement is not None)
        self.detections["ee"] += int(seen_ee)
        q = state.positions_rad[: self.spec.n_joints]
        fk = self.spec.forward_kinematics(q)
        if plate.valid:
            yaw = self._yaw_sign * float(q[0])
            c, s = np.cos(yaw), np.sin(yaw)
            dx, dy, dz = self._offset
            ee = plate.position_m + np.array([c * dx - s * dy, s * dx + c * dy, dz])
            if seen_ee:
                self._fk_bias += 0.2 * ((ee - fk) - self._fk_bias)
        else:
            ee = fk + self._fk_bias
            self.detections["fk_fallback"] += 1
        return Percept(ee_m=ee, goal_m=target.position_m if target.valid else None)

    def close(self) -> None:
        self.frames.close()


class OraclePerception:
    """Ground-truth positions (the ``sim`` backend): the policy still sees servo readings."""

    def __init__(self, ee: Callable[[], np.ndarray], goal: Callable[[], np.ndarray]) -> None:
        self._ee, self._goal = ee, goal

    def reset(self) -> None:
        """Stateless."""

    def perceive(self, state: ArmState, timestamp_s: float) -> Percept:
        return Percept(ee_m=np.array(self._ee()), goal_m=np.array(self._goal()))

    def close(self) -> None:
        """Nothing to release."""
