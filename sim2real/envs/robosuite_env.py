"""robosuite as a second backend: Lift and our Reach through Gymnasium, with the shared DR presets.

Per control step: normalised action → ``RobosuiteActuation`` (noise, latency, speed scale) →
robosuite's controller (OSC or joint space) for ``500/control_hz`` physics steps → sensor models
(joint readings, stereo-shaped position noise, delay) → the shared ``ObservationBuilder``.

Speed choices (measured in ``bench/robosuite_throughput.py``, explained in docs/robosuite.md):
``hard_reset=False`` (robosuite's default recompiles the XML on every reset), every robosuite
observable disabled (we read the few values we need straight from MjData), no robosuite viewer,
and visual DR written only when something renders. The wrapped robosuite env stays reachable as
``env.unwrapped.robosuite_env``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np

from sim2real.envs.base import REWARDS
from sim2real.envs.robosuite_tasks import (
    CONTROLLER_UNITS,
    check_controller,
    check_robot,
    controller_config,
    robosuite,
)
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.model import RigSpec
from sim2real.observation import ObservationBuilder, ObsField
from sim2real.randomization import load_preset
from sim2real.randomization.config import DRConfig
from sim2real.randomization.robosuite_dr import (
    RobosuiteActuation,
    RobosuiteRandomizer,
    RobosuiteTargets,
    noise_per_rad,
)
from sim2real.randomization.sensing import SensorModel
from sim2real.rendering import apply_fast_settings

OBS_MODES: tuple[str, ...] = ("state", "pixels")
IMAGE_SIZES: tuple[int, ...] = (48, 64, 84, 96, 128)
_OFF_FLAGS = (
    mujoco.mjtRndFlag.mjRND_SHADOW,
    mujoco.mjtRndFlag.mjRND_REFLECTION,
    mujoco.mjtRndFlag.mjRND_SKYBOX,
)
_GRIPPER_OPEN = -1.0  # robosuite's gripper command: -1 open, +1 closed


class RobosuiteCamera:
    """Frames from a robosuite camera with the fast CPU settings of NOTES, visual geoms only.

    robosuite puts collision geoms in group 0 and visual meshes in group 1; drawing both doubles
    the scene and z-fights, so group 0 is hidden as robosuite's own renderer does.
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int) -> None:
        apply_fast_settings(model)
        self._renderer = mujoco.Renderer(model, height=height, width=width)
        self._option = mujoco.MjvOption()
        self._option.geomgroup[0] = 0

    def render(self, data: mujoco.MjData, camera: str) -> np.ndarray:
        """(height, width, 3) uint8 RGB, upright."""
        self._renderer.update_scene(data, camera=camera, scene_option=self._option)
        for flag in _OFF_FLAGS:
            self._renderer.scene.flags[flag] = 0
        return self._renderer.render()

    def close(self) -> None:
        self._renderer.close()


def rot6d(R: np.ndarray) -> np.ndarray:
    """(6,) first two columns of a rotation: continuous, unlike a quaternion's sign."""
    return np.concatenate([R[:, 0], R[:, 1]])


# ---- tasks: what differs between Lift and Reach ------------------------------------------------
class RobosuiteTask(ABC):
    """Which robosuite env to build, its task points, fields, success and reward."""

    name: ClassVar[str]
    robosuite_env: ClassVar[str]
    default_controller: ClassVar[str]
    uses_gripper: ClassVar[bool]
    default_episode_steps: ClassVar[int]
    rewards: ClassVar[tuple[str, ...]]
    default_reward: ClassVar[str]

    def robosuite_kwargs(self, reward: str) -> dict[str, Any]:
        return {}

    def object_names(self, rs: Any) -> tuple[str, str, tuple[str, ...], str] | None:
        """(collision geom, body, visual geoms, free joint) of the task object, if any."""
        return None

    @abstractmethod
    def true_points_world(self, rs: Any) -> np.ndarray:
        """(k, 3) positions the cameras observe for this task, world frame."""

    @abstractmethod
    def fields(self, n_gripper: int) -> tuple[ObsField, ...]:
        """Task fields between ``ee_pos`` and ``prev_action``."""

    @abstractmethod
    def readings(self, env: RobosuiteEnv, ee_m: np.ndarray, points_m: np.ndarray) -> dict[str, Any]:
        """Values of ``fields`` from sensed base-frame ee (3,) and task points (k, 3)."""

    @abstractmethod
    def evaluate(self, rs: Any) -> tuple[bool, float]:
        """(success, distance_m) on ground truth."""

    @abstractmethod
    def reward(self, reward_name: str, rs_reward: float, distance_m: float, success: bool) -> float:
        """This step's reward."""


class LiftTask(RobosuiteTask):
    """robosuite's Lift: grasp the cube and hold it 4 cm above the table (robosuite's success)."""

    name = "lift"
    robosuite_env = "Lift"
    default_controller = "OSC_POSE"
    uses_gripper = True
    default_episode_steps = 100  # 5 s at 20 Hz: reach, grasp and lift take about 40 steps
    rewards = ("shaped", "sparse")  # robosuite's own (reward_shaping on/off), max 1 per step
    default_reward = "shaped"
    LIFT_M = 0.04  # robosuite's Lift._check_success margin

    def robosuite_kwargs(self, reward: str) -> dict[str, Any]:
        return {"reward_shaping": reward == "shaped"}

    def object_names(self, rs: Any) -> tuple[str, str, tuple[str, ...], str]:
        cube = rs.cube
        return cube.contact_geoms[0], cube.root_body, tuple(cube.visual_geoms), cube.joints[0]

    def true_points_world(self, rs: Any) -> np.ndarray:
        return np.asarray(rs.sim.data.body_xpos[rs.cube_body_id])[None]

    def fields(self, n_gripper: int) -> tuple[ObsField, ...]:
        return (
            ObsField("gripper_pos", n_gripper, "m", "finger joint positions"),
            ObsField("ee_rot6d", 6, "1", "gripper rotation, first two columns, base frame"),
            ObsField("cube_pos", 3, "m", "cube position estimate, base frame"),
            ObsField("cube_delta", 3, "m", "cube minus end effector"),
            ObsField("cube_rot6d", 6, "1", "cube rotation, first two columns, base frame"),
        )

    def readings(self, env: RobosuiteEnv, ee_m: np.ndarray, points_m: np.ndarray) -> dict[str, Any]:
        data = env.data
        cube_R = data.xmat[env.rs.cube_body_id].reshape(3, 3)
        return {
            "gripper_pos": data.qpos[env.gripper_qadr],
            "ee_rot6d": rot6d(env.base_R.T @ data.site_xmat[env.grip_site].reshape(3, 3)),
            "cube_pos": points_m[0],
            "cube_delta": points_m[0] - ee_m,
            "cube_rot6d": rot6d(env.base_R.T @ cube_R),
        }

    def evaluate(self, rs: Any) -> tuple[bool, float]:
        height = float(rs.sim.data.body_xpos[rs.cube_body_id][2])
        table = float(rs.model.mujoco_arena.table_offset[2])
        return bool(rs._check_success()), max(0.0, table + self.LIFT_M - height)

    def reward(self, reward_name: str, rs_reward: float, distance_m: float, success: bool) -> float:
        return float(rs_reward)


class ReachTask(RobosuiteTask):
    """Our ``Sim2RealReach``: the grip site within 1 cm of a target sampled above the table."""

    name = "reach"
    robosuite_env = "Sim2RealReach"
    default_controller = "OSC_POSITION"
    uses_gripper = False
    default_episode_steps = 50  # as the native reach: 2.5 s at 20 Hz
    rewards = tuple(REWARDS)
    default_reward = "distance"
    SUCCESS_M = 0.01

    def robosuite_kwargs(self, reward: str) -> dict[str, Any]:
        return {"success_m": self.SUCCESS_M}

    def true_points_world(self, rs: Any) -> np.ndarray:
        return rs.target_position()[None]

    def fields(self, n_gripper: int) -> tuple[ObsField, ...]:
        return (
            ObsField("goal_pos", 3, "m", "target position estimate, base frame"),
            ObsField("goal_delta", 3, "m", "target minus end effector"),
        )

    def readings(self, env: RobosuiteEnv, ee_m: np.ndarray, points_m: np.ndarray) -> dict[str, Any]:
        return {"goal_pos": points_m[0], "goal_delta": points_m[0] - ee_m}

    def evaluate(self, rs: Any) -> tuple[bool, float]:
        d = rs.target_distance()
        return d < self.SUCCESS_M, d

    def reward(self, reward_name: str, rs_reward: float, distance_m: float, success: bool) -> float:
        return float(REWARDS[reward_name](distance_m, success))


ROBOSUITE_TASKS: dict[str, type[RobosuiteTask]] = {"lift": LiftTask, "reach": ReachTask}


@dataclass(frozen=True)
class RobosuiteCommand:
    """What one normalised action unit commands through robosuite's controller: the robosuite
    counterpart of the native ``ActionDecoder`` (run dirs record ``max_delta_rad`` from it)."""

    controller: str
    n_actions: int
    max_delta_rad: float  # largest joint or rotation step per control step (0: none in rad)
    max_delta_m: float  # largest Cartesian step per control step (0: joint-space controller)

    @classmethod
    def from_controller(
        cls, controller: str, n_actions: int, units: tuple[str, ...], span: np.ndarray
    ) -> RobosuiteCommand:
        def largest(unit: str) -> float:
            return max(
                (float(s) for u, s in zip(units, span, strict=True) if u == unit), default=0.0
            )

        return cls(controller, n_actions, largest("rad"), largest("m"))


class RobosuiteEnv(gym.Env[np.ndarray, np.ndarray]):
    """A robosuite task behind the same Gymnasium contract as the native arm envs."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}  # noqa: RUF012

    def __init__(
        self,
        task: str = "lift",
        robot: str = "Panda",
        controller: str | None = None,
        dr: str | DRConfig = "default",
        obs_mode: str = "state",
        reward: str | None = None,
        control_hz: float = 20.0,
        max_episode_steps: int | None = None,
        image_size: int = 84,
        camera: str = "agentview",
        render_mode: str | None = None,
        render_width: int = 640,
        render_height: int = 480,
        spec: Any = None,  # accepted for callers that pass the hobby arm's spec to every env
    ) -> None:
        if task not in ROBOSUITE_TASKS:
            raise UnknownNameError("robosuite task", task, ROBOSUITE_TASKS)
        self.task = ROBOSUITE_TASKS[task]()
        self.robot = check_robot(robot)
        self.controller = check_controller(controller or self.task.default_controller)
        reward = reward or self.task.default_reward
        if reward not in self.task.rewards:
            raise UnknownNameError(f"{task} reward", reward, self.task.rewards)
        if obs_mode not in OBS_MODES:
            raise UnknownNameError("obs_mode", obs_mode, OBS_MODES)
        if render_mode not in (None, "rgb_array"):
            raise UnknownNameError("render_mode", str(render_mode), ["rgb_array"])
        if not 1.0 <= control_hz <= 250.0:
            raise ConfigError(f"control_hz {control_hz} not in [1, 250] (physics runs at 500 Hz)")
        steps = self.task.default_episode_steps if max_episode_steps is None else max_episode_steps
        if steps < 1:
            raise ConfigError(f"max_episode_steps {steps} must be >= 1")
        if image_size not in IMAGE_SIZES:
            raise ConfigError(f"image_size {image_size} not one of {list(IMAGE_SIZES)}")
        self.dr_config = load_preset(dr)
        self.obs_mode, self.reward_name = obs_mode, reward
        self.render_mode = render_mode
        self.max_episode_steps = steps
        self.metadata = {**self.metadata, "render_fps": control_hz}

        self.robosuite_env: Any = robosuite.make(
            self.task.robosuite_env,
            robots=self.robot,
            controller_configs=controller_config(self.robot, self.controller),
            has_renderer=False,
            has_offscreen_renderer=False,
            use_camera_obs=False,
            control_freq=control_hz,
            horizon=steps,
            ignore_done=True,  # we truncate; robosuite would raise on a step past its horizon
            hard_reset=False,  # True recompiles the XML at every reset (~0.2 s)
            renderer="mujoco",  # no interactive viewer object
            seed=0,  # construction draws (Lift's cube size) are fixed; episodes reseed at reset
            **self.task.robosuite_kwargs(reward),
        )
        rs = self.robosuite_env
        for name in sorted(rs.observation_names):  # we read MjData directly
            rs.modify_observable(name, "enabled", False)
        self.model: mujoco.MjModel = rs.sim.model._model
        self.data: mujoco.MjData = rs.sim.data._data
        cams = [self.model.camera(i).name for i in range(self.model.ncam)]
        if camera not in cams:
            rs.close()
            raise UnknownNameError("camera", camera, cams)
        self._camera = camera
        self.control_dt_s = 1.0 / control_hz
        self.frame_skip = int(rs.control_timestep / rs.model_timestep)

        arm = rs.robots[0]
        m = self.model
        joints = list(arm.robot_joints)
        self.n_joints = len(joints)
        self.joint_qadr = np.array([m.jnt_qposadr[m.joint(j).id] for j in joints])
        self.joint_dadr = np.array([m.jnt_dofadr[m.joint(j).id] for j in joints])
        gripper = arm.gripper["right"] if arm.has_gripper["right"] else None
        gripper_joints = list(gripper.joints) if gripper is not None else []
        self.gripper_qadr = np.array(
            [m.jnt_qposadr[m.joint(j).id] for j in gripper_joints], dtype=np.intp
        )
        self.grip_site = int(arm.eef_site_id["right"])
        root = m.body(arm.robot_model.root_body).id
        self.base_p = self.data.xpos[root].copy()
        self.base_R = self.data.xmat[root].reshape(3, 3).copy()

        ctrl = arm.part_controllers["right"]
        n_arm = int(ctrl.control_dim)
        n_grip = int(rs.action_dim) - n_arm
        if self.task.uses_gripper and n_grip < 1:
            raise ConfigError(f"robot {robot!r} has no gripper; task {task!r} needs one")
        self._n_arm, self._n_grip = n_arm, n_grip
        self._n_act = n_arm + (n_grip if self.task.uses_gripper else 0)
        self._rs_action = np.zeros(int(rs.action_dim))
        self._rs_action[n_arm:] = _GRIPPER_OPEN
        units = CONTROLLER_UNITS[self.controller](self.n_joints)
        if len(units) != n_arm:
            raise ConfigError(
                f"controller {self.controller} has {n_arm} command dims, expected {len(units)}"
            )
        span_out = np.broadcast_to(np.abs(ctrl.output_max - ctrl.output_min), (n_arm,))
        span_in = np.broadcast_to(np.abs(ctrl.input_max - ctrl.input_min), (n_arm,))
        idle = np.zeros(self._n_act)
        idle[n_arm:] = _GRIPPER_OPEN
        per_unit = span_out / span_in  # physical command per normalised unit, per arm dim
        self.actuation = RobosuiteActuation(idle, n_arm, noise_per_rad(units, per_unit))
        self.decoder = RobosuiteCommand.from_controller(
            self.controller, self._n_act, units, per_unit
        )

        obj = self.task.object_names(rs)
        colour = self._colour_geoms(root, obj)
        self.targets = RobosuiteTargets.from_model(
            m,
            joints,
            list(arm.robot_model.actuators),
            colour,
            obj[0] if obj else None,
            obj[1] if obj else None,
            obj[2] if obj else (),
        )
        self._object_qadr = m.jnt_qposadr[m.joint(obj[3]).id] if obj else -1
        self.randomizer = RobosuiteRandomizer(rs.sim, self.targets, self.dr_config)
        self._renders = obs_mode == "pixels" or render_mode == "rgb_array"

        rig = self._stereo_rig()
        cam0 = rig.cameras[0]
        T = cam0.base_T_cam()
        # Arm encoders: no servo quantisation (resolution 0); positions get the rig's stereo error.
        self.sensors = SensorModel(
            self.n_joints, 0.0, T[:3, :3], T[:3, 3], cam0.focal_px, rig.baseline_m
        )
        self.builder = ObservationBuilder(
            (
                ObsField("joint_pos", self.n_joints, "rad", "arm joint readings"),
                ObsField("joint_vel", self.n_joints, "rad/s", "arm joint velocities"),
                ObsField("ee_pos", 3, "m", "grip site position estimate, base frame"),
                *self.task.fields(len(self.gripper_qadr)),
                ObsField("prev_action", self._n_act, "1", "last normalised action"),
            )
        )
        self.action_space = gym.spaces.Box(-1.0, 1.0, (self._n_act,), dtype=np.float32)
        self.observation_space: gym.spaces.Box
        if obs_mode == "pixels":
            self.observation_space = gym.spaces.Box(
                0, 255, (image_size, image_size, 3), dtype=np.uint8
            )
        else:
            self.observation_space = gym.spaces.Box(
                -np.inf, np.inf, (self.builder.size,), dtype=np.float32
            )
        self._image_size = image_size
        self._render_wh = (render_width, render_height)
        self._pixel_camera: RobosuiteCamera | None = None
        self._frame_camera: RobosuiteCamera | None = None
        self._prev_action = np.zeros(self._n_act)
        self._steps = 0
        self.dr_params: dict[str, Any] = {}
        self._points_buf = np.zeros((2, 3))

    @property
    def rs(self) -> Any:
        return self.robosuite_env

    # ---- gymnasium API ---------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        rng = self.np_random
        self.dr_params = self.randomizer.sample(rng)
        self.randomizer.apply(self.dr_params, visual=self._renders)
        self.actuation.configure(self.dr_params["actuation"])
        self.actuation.reset()
        self.sensors.configure(self.dr_params["sensing"])
        self.sensors.reset()
        # robosuite's own draws (start-pose noise, cube placement, reach target) come from its
        # Generator, shared by its samplers: reseed it in place from our stream.
        episode_rng = np.random.default_rng(int(rng.integers(2**63)))
        self.rs.rng.bit_generator.state = episode_rng.bit_generator.state
        self.rs.reset()
        if self._object_qadr >= 0:
            offset = self.dr_params["object"]["init_xy_offset_m"]
            if np.any(offset):
                self.data.qpos[self._object_qadr : self._object_qadr + 2] += offset
                mujoco.mj_forward(self.model, self.data)
        self._prev_action = np.zeros(self._n_act)
        self._steps = 0
        success, _ = self.task.evaluate(self.rs)
        return self._observe(), {"dr": self.dr_params, "is_success": success}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        a = np.minimum(np.maximum(np.asarray(action, dtype=float), -1.0), 1.0)
        cmd = self.actuation(a, self.np_random)
        self._rs_action[: self._n_act] = cmd
        _, rs_reward, _, _ = self.rs.step(self._rs_action)
        self._prev_action = a
        self._steps += 1
        obs = self._observe()
        success, distance = self.task.evaluate(self.rs)
        reward = self.task.reward(self.reward_name, rs_reward, distance, success)
        truncated = self._steps >= self.max_episode_steps
        return obs, reward, False, truncated, {"is_success": success, "distance_m": distance}

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._frame_camera is None:
            self._frame_camera = RobosuiteCamera(self.model, *self._render_wh)
        return self._frame_camera.render(self.data, self._camera)

    def close(self) -> None:
        for cam in (self._pixel_camera, self._frame_camera):
            if cam is not None:
                cam.close()
        self._pixel_camera = self._frame_camera = None
        self.rs.close()

    # ---- helpers ---------------------------------------------------------------------------
    def restore_nominal(self) -> None:
        """Put every randomised model parameter back to its nominal, bit for bit."""
        self.randomizer.restore_nominal()

    def to_base(self, world_p_m: np.ndarray) -> np.ndarray:
        """(k, 3) world-frame points → robot base frame."""
        return (np.atleast_2d(world_p_m) - self.base_p) @ self.base_R

    def ee_position(self) -> np.ndarray:
        """True grip-site position (3,), base frame."""
        return self.to_base(self.data.site_xpos[self.grip_site])[0]

    def joint_positions(self) -> np.ndarray:
        return self.data.qpos[self.joint_qadr]

    @property
    def steps(self) -> int:
        return self._steps

    def _observe(self) -> np.ndarray:
        if self.obs_mode == "pixels":
            if self._pixel_camera is None:
                size = self._image_size
                self._pixel_camera = RobosuiteCamera(self.model, size, size)
            return self._pixel_camera.render(self.data, self._camera)
        rng = self.np_random
        joints = self.sensors.read_joints(self.data.qpos[self.joint_qadr], rng)
        pts = self._points_buf
        pts[0] = self.ee_position()
        pts[1:] = self.to_base(self.task.true_points_world(self.rs))
        est = self.sensors.read_points(pts, rng)
        joints, est = self.sensors.delay(joints, est)
        readings = {
            "joint_pos": joints,
            "joint_vel": self.data.qvel[self.joint_dadr],
            "ee_pos": est[0],
            **self.task.readings(self, est[0], est[1:]),
            "prev_action": self._prev_action,
        }
        return self.builder.build(readings)

    def _colour_geoms(
        self, robot_root: int, obj: tuple[str, str, tuple[str, ...], str] | None
    ) -> list[str]:
        """Visual geoms whose colour DR jitters: the robot and gripper, the table top, the object
        (as on the native arm: the things a camera-based policy must not key on)."""
        from robosuite.models.tasks.task import get_subtree_geom_ids_by_group

        m = self.model
        ids = get_subtree_geom_ids_by_group(m, robot_root, group=1)
        names = [m.geom(i).name for i in ids if m.geom(i).name]
        names.append("table_visual")
        if obj:
            names += list(obj[2])
        return names

    def _stereo_rig(self) -> RigSpec:
        """Our stereo rig (baseline, fov, distance) aimed at the table centre from the far side,
        in the robot base frame: the stereo noise keys then mean what they mean on the arm."""
        nominal = RigSpec()
        look = self.to_base(self.rs.table_offset)[0]  # Lift and Sim2RealReach: table-top centre
        centre = look + np.subtract(nominal.centre_m, nominal.look_at_m)
        return RigSpec(
            centre_m=(float(centre[0]), float(centre[1]), float(centre[2])),
            look_at_m=(float(look[0]), float(look[1]), float(look[2])),
            baseline_m=nominal.baseline_m,
            fovy_deg=nominal.fovy_deg,
        )
