"""The arm's twin at run time: actuator vectors (rad) ↔ MuJoCo state of a compiled twin model.

The env, ``SimArm`` and the virtual cameras all move the arm through ``ArmTwin``, so the wrist
coupling and the gripper angle ↔ finger mapping live in one place. The model itself is built by
``sim2real.twin_mjcf``.
"""

from __future__ import annotations

import mujoco
import numpy as np

from hardware.spec import ArmSpec
from sim2real.errors import ConfigError
from sim2real.scene_names import FINGER_JOINTS, TOOL_SITE, WRIST_JOINT


def gripper_rad_to_finger_m(spec: ArmSpec, angle_rad: float) -> float:
    """Servo angle of the gripper → slide position of each finger (half the gap)."""
    if spec.gripper is None:
        raise ConfigError(f"spec {spec.name!r} has no gripper")
    return spec.gripper.gap_m(angle_rad) / 2


def finger_m_to_gripper_rad(spec: ArmSpec, finger_m: float) -> float:
    """Inverse of ``gripper_rad_to_finger_m`` (the reading a gripper servo would report)."""
    g = spec.gripper
    if g is None:
        raise ConfigError(f"spec {spec.name!r} has no gripper")
    frac = float(min(max(2 * finger_m / g.max_gap_m, 0.0), 1.0))  # np.clip: 10x on a scalar
    return g.closed_rad + frac * (g.open_rad - g.closed_rad)


class ArmTwin:
    """Actuator vectors (rad) ↔ MuJoCo state for one compiled model, ids resolved once.

    The env, ``SimArm`` and the virtual cameras all move the arm through this, so the wrist
    coupling and the gripper angle ↔ finger mapping live in one place.
    """

    def __init__(self, model: mujoco.MjModel, spec: ArmSpec) -> None:
        self.spec = spec
        self.qadr = np.array([model.joint(n).qposadr[0] for n in spec.joint_names])
        self.dofadr = np.array([model.joint(n).dofadr[0] for n in spec.joint_names])
        self.wrist_qadr = int(model.joint(WRIST_JOINT).qposadr[0])
        self.has_gripper = spec.gripper is not None
        self.finger_qadr = (
            np.array([model.joint(n).qposadr[0] for n in FINGER_JOINTS])
            if self.has_gripper
            else np.zeros(0, dtype=int)
        )
        self.finger_dofadr = (
            np.array([model.joint(n).dofadr[0] for n in FINGER_JOINTS])
            if self.has_gripper
            else np.zeros(0, dtype=int)
        )
        self.tool_site = model.site(TOOL_SITE).id
        self.n_joints = spec.n_joints
        j = spec.joints
        self._s1, self._s2 = j[1].sign, j[2].sign

    def set_pose(self, data: mujoco.MjData, q_rad: np.ndarray, gripper_rad: float | None) -> None:
        """Place the arm kinematically (call mj_forward/mj_kinematics afterwards)."""
        data.qpos[self.qadr] = q_rad[: self.n_joints]
        data.qpos[self.wrist_qadr] = -(self._s1 * q_rad[1] + self._s2 * q_rad[2])
        if self.has_gripper and gripper_rad is not None:
            data.qpos[self.finger_qadr] = gripper_rad_to_finger_m(self.spec, gripper_rad)

    def write_ctrl(
        self, data: mujoco.MjData, joint_ctrl_rad: np.ndarray, gripper_rad: float | None
    ) -> None:
        data.ctrl[: self.n_joints] = joint_ctrl_rad
        if self.has_gripper and gripper_rad is not None:
            data.ctrl[self.n_joints] = gripper_rad_to_finger_m(self.spec, gripper_rad)

    def unjam_fingers(self, data: mujoco.MjData) -> None:
        """Fingers back at rest where their actuator drives them (a simulated cube squeezed out
        of the fingers can leave them jammed); the caller runs mj_forward."""
        if self.has_gripper:
            data.qpos[self.finger_qadr] = data.ctrl[self.n_joints]
            data.qvel[self.finger_dofadr] = 0.0

    def joint_positions(self, data: mujoco.MjData) -> np.ndarray:
        return data.qpos[self.qadr]

    def joint_velocities(self, data: mujoco.MjData) -> np.ndarray:
        return data.qvel[self.dofadr]

    def gripper_rad(self, data: mujoco.MjData) -> float:
        return finger_m_to_gripper_rad(self.spec, float(data.qpos[self.finger_qadr[0]]))

    def actuator_positions(self, data: mujoco.MjData) -> np.ndarray:
        """(n_actuators,) joints then gripper, as a servo bus would list them."""
        q = data.qpos[self.qadr]
        return np.append(q, self.gripper_rad(data)) if self.has_gripper else q.copy()

    def actuator_velocities(self, data: mujoco.MjData) -> np.ndarray:
        """(n_actuators,) rad/s, as ``actuator_positions`` lists them (the gripper's from its
        finger slide, through the linear angle ↔ gap map)."""
        qd = data.qvel[self.dofadr]
        g = self.spec.gripper
        if g is None:
            return qd.copy()
        rad_per_m = 2 * (g.open_rad - g.closed_rad) / g.max_gap_m
        return np.append(qd, rad_per_m * float(data.qvel[self.finger_dofadr[0]]))

    def tool_position(self, data: mujoco.MjData) -> np.ndarray:
        return data.site_xpos[self.tool_site]
