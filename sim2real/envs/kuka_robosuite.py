"""The faithful twin of the Kuka grasping task: robosuite's KUKA IIWA with its Robotiq gripper.

Same task, spaces and object set as ``KukaGraspFastEnv`` (``kuka_grasp.py`` documents both): a
tray on robosuite's table, ``MAX_SLOTS`` composite-object slots rewritten per episode, a camera at
the same pose relative to the tray, 48×48 pixels. The arm is driven by robosuite's operational-space
controller (OSC_POSE) towards the same Cartesian target the fast twin's gripper tracks, so the
height hack and the actions mean the same thing on both: the target moves, the arm follows.

Speed choices (as ``robosuite_env``): ``hard_reset=False``, every robosuite observable disabled,
pixels from our own fast renderer. The start pose comes from a small damped least-squares IK at
construction, so no reset spends steps moving the arm into place.

DR: the shared samplers, applied by the robosuite backend's ``RobosuiteRandomizer`` (``dynamics``
on the IIWA links and joints, ``visual`` on lights, cameras and colours); ``object`` goes through
the slot writer; ``actuation`` and ``sensing`` as on the fast twin (``IGNORED_DR_KEYS``).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from typing import Any

import mujoco
import numpy as np

from sim2real.envs import kuka_objects as ko
from sim2real.envs.kuka_grasp import (
    CAMERA,
    CAMERA_FOVY_DEG,
    CONTROL_DT_S,
    MAX_SLOTS,
    GraspTask,
    KukaGraspBase,
    apply_pixel_settings,
    camera_pose,
)
from sim2real.envs.robosuite_tasks import check_robot, controller_config
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.randomization.config import DRConfig
from sim2real.randomization.robosuite_compat import import_robosuite
from sim2real.randomization.robosuite_dr import RobosuiteRandomizer, RobosuiteTargets
from sim2real.rendering import apply_fast_settings

import_robosuite()
from robosuite.environments.manipulation.manipulation_env import (  # noqa: E402
    ManipulationEnv,
)
from robosuite.models.arenas import TableArena  # noqa: E402
from robosuite.models.grippers import GRIPPER_MAPPING  # noqa: E402
from robosuite.models.objects import CompositeObject  # noqa: E402
from robosuite.models.tasks import ManipulationTask  # noqa: E402
from robosuite.models.tasks.task import get_subtree_geom_ids_by_group  # noqa: E402

TABLE_TOP_M = 0.8  # robosuite's table-top height (table_offset z)
TRAY_FLOOR_M = 0.005  # the tray floor sits on the table: tray-frame z = 0 is its top
TRAY_HALF_M = 0.15
TRAY_ORIGIN_M = np.array([0.0, 0.0, TABLE_TOP_M + TRAY_FLOOR_M])
OSC_POS_M = 0.05  # OSC_POSE output_max: one normalised unit of position command
OSC_ROT_RAD = 0.5  # ... and of rotation command
GRIP_OPEN, GRIP_CLOSED = -1.0, 1.0
# Grasp phase in control steps (50 ms each): reach the bottom, close, lift (ramp), hold.
REACH_STEPS = 3
CLOSE_STEPS = 8
LIFT_STEPS = 6
HOLD_STEPS = 2
LEAD = 1.5  # feed-forward: the goal leads the target by this many steps of its motion
KI = 0.4  # integral gain per control step on the grip-site position error
BIAS_MAX_M = 0.015
PARK_XY_M = (1.5, 1.5)


def _tray_xml(arena: TableArena) -> None:
    """Tray floor and walls on the table (group 1: drawn and colliding)."""
    top = TABLE_TOP_M
    w = TRAY_HALF_M + 0.005
    geoms = [
        ("kuka_tray", (TRAY_HALF_M, TRAY_HALF_M, TRAY_FLOOR_M / 2), (0, 0, top + TRAY_FLOOR_M / 2)),
        ("kuka_wall_n", (w, 0.005, 0.015), (0, w, top + 0.015)),
        ("kuka_wall_s", (w, 0.005, 0.015), (0, -w, top + 0.015)),
        ("kuka_wall_e", (0.005, w, 0.015), (w, 0, top + 0.015)),
        ("kuka_wall_w", (0.005, w, 0.015), (-w, 0, top + 0.015)),
    ]
    for name, size, pos in geoms:
        rgba = "0.75 0.7 0.6 1" if name == "kuka_tray" else "0.45 0.35 0.25 1"
        arena.worldbody.append(
            ET.Element(
                "geom",
                name=name,
                type="box",
                size=" ".join(f"{v:g}" for v in size),
                pos=" ".join(f"{v:g}" for v in pos),
                rgba=rgba,
                group="1",
                contype="1",
                conaffinity="1",
            )
        )


class KukaGraspScene(ManipulationEnv):
    """robosuite side: the table, the tray, the tray camera and the object slots."""

    def __init__(self, robots: Any, **kwargs: Any) -> None:
        self.table_full_size = (0.8, 0.8, 0.05)
        self.table_offset = np.array((0.0, 0.0, TABLE_TOP_M))
        super().__init__(robots=robots, **kwargs)

    def _load_model(self) -> None:
        super()._load_model()
        robot_model = self.robots[0].robot_model
        robot_model.set_base_xpos(robot_model.base_xpos_offset["table"](self.table_full_size[0]))
        arena = TableArena(table_full_size=self.table_full_size, table_offset=self.table_offset)
        arena.set_origin([0, 0, 0])
        _tray_xml(arena)
        pos, quat = camera_pose(TRAY_ORIGIN_M)
        arena.set_camera(CAMERA, pos, quat, camera_attribs={"fovy": f"{CAMERA_FOVY_DEG:g}"})
        self.slot_objects = [
            CompositeObject(
                name=f"kuka_obj{i}",
                total_size=[0.03, 0.03, 0.03],
                geom_types=["box"] * ko.MAX_PARTS,
                geom_sizes=[[0.01, 0.01, 0.01]] * ko.MAX_PARTS,
                geom_locations=[[0.0, 0.0, 0.0]] * ko.MAX_PARTS,
                locations_relative_to_center=True,
                density=500.0,
                rgba=[0.5, 0.5, 0.5, 1.0],
            )
            for i in range(MAX_SLOTS)
        ]
        self.model = ManipulationTask(
            mujoco_arena=arena,
            mujoco_robots=[r.robot_model for r in self.robots],
            mujoco_objects=self.slot_objects,
        )

    def reward(self, action: Any = None) -> float:
        return 0.0  # the Gymnasium env judges the grasp at the end of the episode

    def _check_success(self) -> bool:
        return False


# The Robotiq 85 opens 85 mm: close to the fast twin's 90 mm (the IIWA's default Robotiq 140
# opens 140 mm and makes blind grasps twice as likely as on the fast twin).
GRIPPER = "Robotiq140Gripper"
OSC_KP = 300.0  # robosuite's upper kp limit: a 50 ms step reaches most of a 1.5 cm move


def _stiff_osc(robot: str) -> dict[str, Any]:
    config = controller_config(robot, "OSC_POSE")
    config["body_parts"]["right"]["kp"] = OSC_KP
    return config


DRAWN_GROUP, HIDDEN_GROUP = 2, 3
_OFF_FLAGS = (
    mujoco.mjtRndFlag.mjRND_SHADOW,
    mujoco.mjtRndFlag.mjRND_REFLECTION,
    mujoco.mjtRndFlag.mjRND_SKYBOX,
)
ROBOT_RGBA = (0.25, 0.25, 0.27, 1.0)


def draw_collision_meshes(model: mujoco.MjModel) -> np.ndarray:
    """Draw the robot's collision meshes instead of its visual ones: 66k instead of 250k
    triangles, 3 ms instead of 11 ms per 48 px frame on llvmpipe, and at 48 px the arm looks
    the same. Returns the geoms now drawn for the robot (the colours visual DR jitters)."""
    meshes = model.geom_type == mujoco.mjtGeom.mjGEOM_MESH
    visual = np.flatnonzero(meshes & (model.geom_group == 1))
    collision = np.flatnonzero(meshes & (model.geom_group == 0))
    model.geom_group[visual] = HIDDEN_GROUP
    model.geom_group[collision] = DRAWN_GROUP
    model.geom_rgba[collision] = ROBOT_RGBA
    model.geom_matid[collision] = -1
    return collision


class TrayCamera:
    """Frames with the fast CPU settings, skipping collision primitives (group 0) and the hidden
    visual meshes; close it explicitly."""

    def __init__(self, model: mujoco.MjModel, width: int, height: int) -> None:
        apply_fast_settings(model)
        self._renderer = mujoco.Renderer(model, height=height, width=width)
        self._option = mujoco.MjvOption()
        self._option.geomgroup[0] = 0
        self._option.geomgroup[HIDDEN_GROUP] = 0

    def render(self, data: mujoco.MjData, camera: str) -> np.ndarray:
        self._renderer.update_scene(data, camera=camera, scene_option=self._option)
        for flag in _OFF_FLAGS:
            self._renderer.scene.flags[flag] = 0
        return self._renderer.render()

    def close(self) -> None:
        self._renderer.close()


def _rotvec(R: np.ndarray) -> np.ndarray:
    """Axis-angle vector of a rotation matrix (3,)."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, R.reshape(-1))
    v = np.zeros(3)
    mujoco.mju_quat2Vel(v, q, 1.0)
    return v


def _rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def solve_ik(
    model: mujoco.MjModel,
    qpos: np.ndarray,
    site: int,
    qadr: np.ndarray,
    dadr: np.ndarray,
    target_p: np.ndarray,
    target_R: np.ndarray,
    iterations: int = 200,
    damping: float = 1e-2,
) -> np.ndarray:
    """Joint positions (len(qadr),) that put ``site`` at ``target_p`` with ``target_R``
    (damped least squares on a scratch MjData, so the live one is untouched)."""
    d = mujoco.MjData(model)
    d.qpos[:] = qpos
    jacp = np.zeros((3, model.nv))
    jacr = np.zeros((3, model.nv))
    lo, hi = model.jnt_range[model.dof_jntid[dadr]].T
    for _ in range(iterations):
        mujoco.mj_kinematics(model, d)
        mujoco.mj_comPos(model, d)
        err = np.concatenate(
            [
                target_p - d.site_xpos[site],
                _rotvec(target_R @ d.site_xmat[site].reshape(3, 3).T),
            ]
        )
        if np.linalg.norm(err) < 1e-6:
            break
        mujoco.mj_jacSite(model, d, jacp, jacr, site)
        J = np.vstack([jacp[:, dadr], jacr[:, dadr]])
        dq = J.T @ np.linalg.solve(J @ J.T + damping**2 * np.eye(6), err)
        d.qpos[qadr] = np.clip(d.qpos[qadr] + dq, lo, hi)
    return d.qpos[qadr].copy()


class KukaGraspEnv(KukaGraspBase):
    """The Kuka grasping task on robosuite's IIWA (see the module docstring)."""

    def __init__(
        self,
        actions: str = "discrete",
        dr: str | DRConfig = "default",
        objects: str = "train",
        image_size: int = 48,
        max_episode_steps: int | None = None,
        task: GraspTask | None = None,
        robot: str = "IIWA",
        gripper: str = GRIPPER,
        render_mode: str | None = None,
        render_width: int = 320,
        render_height: int = 240,
        spec: Any = None,  # accepted (and unused) so callers can pass the arm spec to every env
    ) -> None:
        super().__init__(actions, dr, objects, image_size, max_episode_steps, task, render_mode)
        self.robot = check_robot(robot)
        grippers = sorted(k for k in GRIPPER_MAPPING if k)
        if gripper not in grippers:
            raise UnknownNameError("robosuite gripper", gripper, grippers)
        self.robosuite_env: Any = KukaGraspScene(
            robots=self.robot,
            controller_configs=_stiff_osc(self.robot),
            gripper_types=gripper,
            has_renderer=False,
            has_offscreen_renderer=False,
            use_camera_obs=False,
            control_freq=1.0 / CONTROL_DT_S,
            horizon=10_000,
            ignore_done=True,  # we end episodes; robosuite would raise on a step past its horizon
            hard_reset=False,  # True recompiles the XML at every reset
            renderer="mujoco",
            seed=0,
        )
        rs = self.robosuite_env
        for name in sorted(rs.observation_names):  # we render and read MjData ourselves
            rs.modify_observable(name, "enabled", False)
        self.model: mujoco.MjModel = rs.sim.model._model
        self.data: mujoco.MjData = rs.sim.data._data
        m = self.model
        ko.prepare_model(m)
        apply_pixel_settings(m, headlight=True)  # robosuite's lights are dim without it
        self.frame_skip = int(rs.control_timestep / rs.model_timestep)
        self.slots = tuple(
            ko.Slot.from_names(m, o.root_body, o.contact_geoms, o.visual_geoms)
            for o in rs.slot_objects
        )
        arm = rs.robots[0]
        joints = list(arm.robot_joints)
        self._qadr = np.array([m.joint(j).qposadr[0] for j in joints], dtype=np.intp)
        self._dadr = np.array([m.joint(j).dofadr[0] for j in joints], dtype=np.intp)
        self._site = int(arm.eef_site_id["right"])
        self._n_act = int(rs.action_dim)
        if self._n_act != int(arm.part_controllers["right"].control_dim) + 1:
            raise ConfigError(f"robot {robot!r} needs a one-dof gripper for the grasp task")
        self._rs_action = np.zeros(self._n_act)

        rs.reset()
        self._gripper_geoms = self._collision_geoms(arm)
        self._tip_offset_m = self._lowest_tip_offset()
        self._R0 = self.data.site_xmat[self._site].reshape(3, 3).copy()  # pointing down
        self._q_centre = self._start_qpos(np.zeros(2), self.data.qpos)

        robot_geoms = draw_collision_meshes(m)
        colour = [m.geom(int(g)).name for g in robot_geoms]
        colour = [n for n in colour if n] + ["table_visual", "kuka_tray"]
        self.targets = RobosuiteTargets.from_model(
            m, joints, list(arm.robot_model.actuators), colour, None, None
        )
        self.randomizer = RobosuiteRandomizer(rs.sim, self.targets, self.dr_config)
        self._prev_target = np.zeros(4)
        self._bias = np.zeros(3)
        self._render_wh = (render_width, render_height)
        self._pixel_camera: TrayCamera | None = None
        self._frame_camera: TrayCamera | None = None

    @property
    def rs(self) -> Any:
        return self.robosuite_env

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._frame_camera is None:
            self._frame_camera = TrayCamera(self.model, *self._render_wh)
        return self._frame_camera.render(self.data, CAMERA)

    def close(self) -> None:
        for cam in (self._pixel_camera, self._frame_camera):
            if cam is not None:
                cam.close()
        self._pixel_camera = self._frame_camera = None
        self.rs.close()

    def restore_nominal(self) -> None:
        """Put every DR-randomised model parameter back to its nominal, bit for bit."""
        self.randomizer.restore_nominal()

    def gripper_pose(self) -> np.ndarray:
        p = self.data.site_xpos[self._site] - TRAY_ORIGIN_M
        R = self.data.site_xmat[self._site].reshape(3, 3) @ self._R0.T
        return np.array([p[0], p[1], p[2] - self._tip_offset_m, math.atan2(R[1, 0], R[0, 0])])

    def object_positions(self) -> np.ndarray:
        body = [self.slots[k].body for k in range(len(self._live))]
        return self.data.xpos[body] - TRAY_ORIGIN_M

    def set_object_pose(self, slot: int, xy_m: tuple[float, float], yaw_rad: float = 0.0) -> None:
        self._check_slot(slot)
        z = float(self._half_heights[slot]) + 0.001
        pos = TRAY_ORIGIN_M + (xy_m[0], xy_m[1], z)
        ko.place(self.data, self.slots[slot], pos.tolist(), yaw_rad)
        mujoco.mj_forward(self.model, self.data)
        self._distance_m = self.nearest_object_xy_m()
        self._obs = self._pixels()

    # ---- hooks --------------------------------------------------------------------------------
    def _sample_dr(self, rng: np.random.Generator) -> dict[str, Any]:
        params = self.randomizer.sample(rng)
        self.randomizer.apply(params, visual=True)
        return params

    def _reset_scene(
        self,
        rng: np.random.Generator,
        chosen: np.ndarray,
        obj: dict[str, Any],
        centres_m: np.ndarray,
        yaws_rad: np.ndarray,
        clear: bool,
    ) -> None:
        m, d = self.model, self.data
        self._write_objects(chosen, obj)  # before robosuite's reset: it rewinds qpos
        # The arm starts exactly at the (jittered) start target, as the fast twin's gripper does.
        seed_qpos = d.qpos.copy()
        seed_qpos[self._qadr] = self._q_centre
        self.rs.robots[0].init_qpos = self._start_qpos(self._target[:2], seed_qpos)
        # robosuite's own draws (none by default) come from its Generator: reseed it from ours.
        episode_rng = np.random.default_rng(int(rng.integers(2**63)))
        self.rs.rng.bit_generator.state = episode_rng.bit_generator.state
        self.rs.reset()
        for k, slot in enumerate(self.slots):
            if k < len(chosen):
                z = self._half_heights[k] + (0.001 if clear else 0.07 * k + 0.001)
                pos = TRAY_ORIGIN_M + (centres_m[k, 0], centres_m[k, 1], z)
                ko.place(d, slot, pos.tolist(), float(yaws_rad[k]))
            else:
                ko.park(m, d, slot, (PARK_XY_M[0] + 0.2 * k, PARK_XY_M[1]))
                d.qpos[slot.qpos_adr + 2] = ko.PARK_RADIUS_M  # robosuite's floor is at z = 0
        mujoco.mj_forward(m, d)
        self._prev_target[:] = self._target
        self._bias[:] = 0.0
        self._drive(GRIP_OPEN, 1 if clear else 4)

    def _track_target(self) -> None:
        lead = LEAD * (self._target[:3] - self._prev_target[:3])
        self._prev_target[:] = self._target
        self._drive(GRIP_OPEN, 1, lead)

    def _close_and_lift(self) -> None:
        self._drive(GRIP_OPEN, REACH_STEPS)
        self._drive(GRIP_CLOSED, CLOSE_STEPS)
        z0 = float(self._target[2])
        rise = (self.task.lift_to_m - z0) / LIFT_STEPS
        for k in range(1, LIFT_STEPS + 1):
            self._target[2] = z0 + rise * k
            self._drive(GRIP_CLOSED, 1, np.array([0.0, 0.0, LEAD * rise]))
        self._drive(GRIP_CLOSED, HOLD_STEPS)

    def _drive(self, gripper: float, steps: int, lead_m: np.ndarray | None = None) -> None:
        """robosuite steps with the OSC commanded from the current pose to the target (a delta
        per step, so tracking errors never accumulate the way chained deltas would). ``lead_m``
        feeds the target's motion forward: the OSC alone trails a moving target by ~2 cm."""
        d, a = self.data, self._rs_action
        x, y, z, yaw = self._target
        goal_p = TRAY_ORIGIN_M + (x, y, z + self._tip_offset_m)
        if lead_m is not None:
            goal_p = goal_p + lead_m
        goal_R = _rot_z(yaw) @ self._R0
        for _ in range(steps):
            err = goal_p - d.site_xpos[self._site]
            if lead_m is None:
                # Integral action on a still target: the OSC's P term alone stops ~1 cm short
                # against the IIWA's joint friction and damping (on a moving target the lead
                # does that job, and integrating the lag would overshoot).
                self._bias = np.clip(self._bias + KI * err, -BIAS_MAX_M, BIAS_MAX_M)
            a[:3] = (err + self._bias) / OSC_POS_M
            a[3:6] = _rotvec(goal_R @ d.site_xmat[self._site].reshape(3, 3).T) / OSC_ROT_RAD
            np.clip(a[:6], -1.0, 1.0, out=a[:6])
            a[6:] = gripper
            self.rs.step(a)

    def _pixels(self) -> np.ndarray:
        if self._pixel_camera is None:
            size = self._image_size
            self._pixel_camera = TrayCamera(self.model, size, size)
        return self._pixel_camera.render(self.data, CAMERA)

    # ---- construction helpers --------------------------------------------------------------
    def _start_qpos(self, xy_m: np.ndarray, seed_qpos: np.ndarray) -> np.ndarray:
        """Arm joints putting the open gripper at the start height above tray point ``xy_m``."""
        z = self.task.start_height_m + self._tip_offset_m
        goal = TRAY_ORIGIN_M + (float(xy_m[0]), float(xy_m[1]), z)
        return solve_ik(self.model, seed_qpos, self._site, self._qadr, self._dadr, goal, self._R0)

    def _collision_geoms(self, arm: Any) -> np.ndarray:
        m = self.model
        root = m.body(arm.gripper["right"].root_body).id
        ids = get_subtree_geom_ids_by_group(m, root, group=0)
        return np.array(
            [g for g in ids if m.geom_contype[g] or m.geom_conaffinity[g]], dtype=np.intp
        )

    def _lowest_tip_offset(self) -> float:
        """Height of the grip site above the lowest point of the open gripper's collision geoms."""
        m, d = self.model, self.data
        g = self._gripper_geoms
        R = d.geom_xmat[g].reshape(-1, 3, 3)
        centre_z = d.geom_xpos[g, 2] + np.einsum("kj,kj->k", R[:, 2, :], m.geom_aabb[g, :3])
        half_z = np.einsum("kj,kj->k", np.abs(R[:, 2, :]), m.geom_aabb[g, 3:])
        return float(d.site_xpos[self._site][2] - np.min(centre_z - half_z))


__all__ = ["KukaGraspEnv", "KukaGraspScene", "solve_ik"]
