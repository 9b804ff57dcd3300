"""Kuka grasping from 48×48 pixels: the seed project's task, as a fast native MuJoCo twin.

The task (shared with the robosuite IIWA twin in ``kuka_robosuite.py``): a parallel gripper starts
above a tray of 1–5 random objects from the shipped generated set. Every step moves it by one of
7 discrete actions (no-op, ±x, ±y, ±yaw) — or a continuous (dx, dy, dyaw) in the ``Cont``
variants — and *also* lowers it by a fixed amount: the seed's "height hack", which removes the
hardest part of exploration (when to go down). When the gripper reaches the bottom, or at the last
step, it closes and lifts; the reward is 1 if any object is then above the lift height, else 0.

The fast twin is a floating gripper on slide/hinge joints (position actuators, gravity
compensated) instead of an arm: same action and observation spaces, a fraction of the cost. Objects
live in fixed slots rewritten per episode (``kuka_objects``), so a reset never recompiles anything.

Domain randomisation reuses the shared layers (``sim2real.randomization``) with the ids of this
model: ``visual`` (lights, colours of tray and gripper, camera pose and fov) and ``dynamics``
(gripper link masses, joint damping/friction/armature, actuator gains) apply as they are;
``object`` (size, mass, friction, spawn offset) is applied per object by the slot writer;
``actuation`` maps ``latency_steps`` (actions arrive late), ``max_speed_scale`` (shorter moves) and
``action_noise_rad`` (yaw jitter). Not applicable, sampled but ignored: ``actuation.deadband_rad``
and ``actuation.quantisation_rad`` (hobby-servo effects; this gripper is not a hobby servo), all
of ``sensing`` (the policy sees pixels only; the joint and stereo sensor models have no input here)
and all of ``kinematics`` (the hobby arm's link lengths and zero offsets; there is no such arm).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections import deque
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from sim2real.envs import kuka_objects as ko
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.observation import ObservationBuilder, ObsField
from sim2real.randomization import DomainRandomizer, ModelIds, load_preset
from sim2real.randomization.config import DRConfig
from sim2real.rendering import FastRenderer

# The seed's 7 discrete actions as unit moves (dx, dy, dyaw); the height hack adds the descent.
DISCRETE_ACTIONS: np.ndarray = np.array(
    [
        [0.0, 0.0, 0.0],  # 0 no-op (descend only)
        [1.0, 0.0, 0.0],  # 1 +x
        [-1.0, 0.0, 0.0],  # 2 -x
        [0.0, 1.0, 0.0],  # 3 +y
        [0.0, -1.0, 0.0],  # 4 -y
        [0.0, 0.0, 1.0],  # 5 +yaw
        [0.0, 0.0, -1.0],  # 6 -yaw
    ]
)
ACTION_NAMES: tuple[str, ...] = ("noop", "+x", "-x", "+y", "-y", "+yaw", "-yaw")
ACTION_MODES: tuple[str, ...] = ("discrete", "continuous")
IMAGE_SIZES: tuple[int, ...] = (48, 64, 84, 96, 128)
CAMERA = "tray_cam"
MAX_SLOTS = 5  # objects per episode at most: the model has this many object slots
# The privileged state: what the simulator knows and a camera does not. Training code reads it from
# ``info[PRIVILEGED_INFO_KEY]`` (reset and step) for an asymmetric critic or a DAgger teacher; the
# observation, and so every exported actor, never contains it. Positions are in units of
# ``PRIVILEGED_SCALE_M`` (about [-2, 2] over the tray), so a critic MLP needs no normaliser.
PRIVILEGED_INFO_KEY = "privileged_state"
PRIVILEGED_SCALE_M = 0.1
PRIVILEGED_FIELDS: tuple[str, ...] = (
    "target_x",  # commanded gripper pose, tray frame, / PRIVILEGED_SCALE_M
    "target_y",
    "target_z",
    "target_yaw_rad",
    "episode_fraction",  # steps taken / max_episode_steps
    *(
        f"obj{k}_{f}"  # per slot: 1 if live, object centre minus target (xy) and height, scaled
        for k in range(MAX_SLOTS)
        for f in ("present", "dx", "dy", "z")
    ),
)
IGNORED_DR_KEYS: dict[str, tuple[str, ...]] = {
    "actuation": ("deadband_rad", "quantisation_rad"),
    "kinematics": ("link_length_delta_m", "joint_offset_rad", "tool_offset_delta_m"),
    "sensing": (
        "joint_noise_rad",
        "joint_bias_rad",
        "stereo_pixel_noise_px",
        "position_bias_m",
        "obs_delay_steps",
    ),
}


@dataclass(frozen=True)
class GraspTask:
    """Geometry and timing of the task, shared by both twins. Heights are of the fingertips
    above the tray floor; xy is relative to the tray centre."""

    start_height_m: float = 0.158
    bottom_height_m: float = 0.008
    descent_steps: int = 12  # the height hack reaches the bottom on this step
    xy_step_m: float = 0.015  # one ±x/±y action
    yaw_step_rad: float = 0.2  # one ±yaw action
    workspace_half_m: float = 0.10  # the gripper target stays in this square
    spawn_half_m: float = 0.075  # object centres are drawn in this square
    start_jitter_m: float = 0.02  # the gripper starts near the tray centre
    lift_to_m: float = 0.20
    lift_success_m: float = 0.12  # an object's centre above this at the end is a grasp
    min_objects: int = 1
    max_objects: int = 5

    def __post_init__(self) -> None:
        if not 0 < self.bottom_height_m < self.start_height_m:
            raise ConfigError(
                f"heights: need 0 < bottom {self.bottom_height_m} < start {self.start_height_m}"
            )
        if self.descent_steps < 1:
            raise ConfigError(f"descent_steps {self.descent_steps} must be >= 1")
        for name in ("xy_step_m", "yaw_step_rad", "workspace_half_m", "spawn_half_m"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} {getattr(self, name)} must be > 0")
        if not 1 <= self.min_objects <= self.max_objects <= MAX_SLOTS:
            raise ConfigError(
                f"object count [{self.min_objects}, {self.max_objects}] not within [1, {MAX_SLOTS}]"
            )
        if not self.lift_success_m < self.lift_to_m:
            raise ConfigError(
                f"lift_success_m {self.lift_success_m} must be below lift_to_m {self.lift_to_m}"
            )

    @property
    def descent_m_per_step(self) -> float:
        return (self.start_height_m - self.bottom_height_m) / self.descent_steps


@dataclass(frozen=True)
class GraspActionDecoder:
    """Policy action → (dx_m, dy_m, dyaw_rad) of the gripper target: the action contract of both
    twins (the descent is added by the env, not the policy)."""

    discrete: bool
    xy_step_m: float
    yaw_step_rad: float

    @property
    def n_actions(self) -> int:
        return len(DISCRETE_ACTIONS) if self.discrete else 3

    @property
    def max_delta_rad(self) -> float:
        return self.yaw_step_rad

    @property
    def max_delta_m(self) -> float:
        return self.xy_step_m

    def unit_move(self, action: Any) -> np.ndarray:
        """(3,) move in units of one step: a table row, or the clipped continuous action."""
        if self.discrete:
            a = np.asarray(action)
            if a.size != 1 or not np.isfinite(a).all():
                raise ConfigError(f"discrete action {action!r} must be one integer in [0, 6]")
            i = int(a.reshape(()))
            if i != a.reshape(()) or not 0 <= i < len(DISCRETE_ACTIONS):
                raise ConfigError(
                    f"discrete action {action!r} not in [0, {len(DISCRETE_ACTIONS) - 1}]"
                )
            return DISCRETE_ACTIONS[i]
        a = np.asarray(action, dtype=float).reshape(-1)
        if a.shape != (3,):
            raise ConfigError(f"continuous action {action!r} must have 3 values (dx, dy, dyaw)")
        if not np.isfinite(a).all():
            raise ConfigError(f"continuous action {a.tolist()} contains NaN or inf")
        return np.minimum(np.maximum(a, -1.0), 1.0)

    def decode(self, action: Any) -> np.ndarray:
        u = self.unit_move(action)
        return np.array([u[0] * self.xy_step_m, u[1] * self.xy_step_m, u[2] * self.yaw_step_rad])


def action_space_for(mode: str) -> gym.spaces.Space[Any]:
    if mode not in ACTION_MODES:
        raise UnknownNameError("action mode", mode, ACTION_MODES)
    if mode == "discrete":
        return gym.spaces.Discrete(len(DISCRETE_ACTIONS))
    return gym.spaces.Box(-1.0, 1.0, (3,), dtype=np.float32)


class GraspActuation:
    """The ``actuation`` DR keys that mean something for a Cartesian gripper: late actions, a
    slower arm (shorter moves) and yaw jitter."""

    def __init__(self) -> None:
        self.latency_steps = 0
        self.speed_scale = 1.0
        self.yaw_noise_rad = 0.0
        self._queue: deque[np.ndarray] = deque()

    def configure(self, params: dict[str, Any]) -> None:
        self.latency_steps = int(params["latency_steps"])
        self.speed_scale = float(params["max_speed_scale"])
        self.yaw_noise_rad = float(params["action_noise_rad"])

    def reset(self) -> None:
        self._queue = deque(np.zeros(3) for _ in range(self.latency_steps))

    def __call__(self, move: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        if self.latency_steps:
            self._queue.append(move)
            move = self._queue.popleft()
        out = move * self.speed_scale
        if self.yaw_noise_rad > 0:
            out[2] += self.yaw_noise_rad * rng.standard_normal()
        return out


def nearest_object_offset(privileged: np.ndarray) -> np.ndarray | None:
    """(2,) the live object nearest the gripper target, minus the target (x, y), in units of
    ``PRIVILEGED_SCALE_M``; None when no object is live. What the scripted servo steers on, and so
    what a pixel student must see to imitate it (an auxiliary regression target)."""
    p = np.asarray(privileged, dtype=np.float64).reshape(-1)
    if p.shape != (len(PRIVILEGED_FIELDS),):
        raise ConfigError(
            f"privileged state has {p.size} values, expected {len(PRIVILEGED_FIELDS)}"
        )
    slots = p[5:].reshape(MAX_SLOTS, 4)
    live = slots[slots[:, 0] > 0.5]
    if len(live) == 0:
        return None
    err = live[:, 1:3]
    return err[int(np.argmin(np.einsum("ij,ij->i", err, err)))]


def privileged_teacher_action(privileged: np.ndarray, xy_step_m: float = 0.015) -> int:
    """The scripted servo as a pure function of the privileged state (a DAgger teacher): move along
    the larger horizontal error to the live object nearest the target, or descend only when both
    are within half a step. Yaw is left alone, as in the bench servo."""
    offset = nearest_object_offset(privileged)
    if offset is None:
        return 0
    err = offset * PRIVILEGED_SCALE_M
    if np.max(np.abs(err)) < 0.5 * xy_step_m:
        return 0
    axis = int(np.argmax(np.abs(err)))
    return 1 + 2 * axis + int(err[axis] < 0)  # +x, -x, +y, -y are actions 1, 2, 3, 4


def pixel_builder(image_size: int) -> ObservationBuilder:
    """The layout ``sim2real envs --layout`` and run dirs record for the pixel observation."""
    return ObservationBuilder(
        (
            ObsField(
                "rgb", image_size * image_size * 3, "uint8", f"{image_size}x{image_size} RGB, HWC"
            ),
        )
    )


# ---- the native model ----------------------------------------------------------------------------
TRAY_HALF_M = 0.15
PARK_Y_M = 1.5  # unused slots rest on the floor here, out of every view
FINGER_OPEN_M = 0.06  # each finger's inner face from the centre: 12 cm, as the IIWA's Robotiq 140
PHYSICS_TIMESTEP_S = 0.005
CONTROL_DT_S = 0.05
GRIPPER_JOINTS = ("grip_x", "grip_y", "grip_z", "grip_yaw")
GRIPPER_BODIES = ("gripper", "finger_left", "finger_right")
COLOUR_GEOMS = (
    "tray",
    "wall_n",
    "wall_s",
    "wall_e",
    "wall_w",
    "palm",
    "finger_left",
    "finger_right",
)
# Grasp phase, in physics steps: close, lift (in ramp chunks), hold.
CLOSE_STEPS = 55
LIFT_CHUNKS = 5
LIFT_CHUNK_STEPS = 8
HOLD_STEPS = 15
SETTLE_STEPS = 15
STACKED_SETTLE_STEPS = 100


def apply_pixel_settings(model: mujoco.MjModel, headlight: bool = False) -> None:
    """On top of ``FastRenderer``'s settings: coarser curved surfaces (invisible at 48 px) and,
    where the scene has its own lights, no headlight; about 25% less render time on llvmpipe."""
    model.vis.quality.numslices = 12
    model.vis.quality.numstacks = 6
    model.vis.headlight.active = int(headlight)


CAMERA_OFFSET_M = (0.0, -0.30, 0.62)  # from the tray centre: in front of and above it
CAMERA_FOVY_DEG = 30.0


def camera_pose(tray_origin_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(pos, quat wxyz) of the tray camera looking at the tray centre: both twins use it."""
    pos = np.asarray(tray_origin_m, dtype=float) + CAMERA_OFFSET_M
    forward = tray_origin_m - pos
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, (0.0, 0.0, 1.0))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    R = np.column_stack([right, up, -forward])  # MuJoCo cameras look along their -z
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, R.reshape(-1))
    return pos, quat


def _vec(v: Any) -> str:
    return " ".join(f"{float(x):.6g}" for x in v)


def build_fast_mjcf(task: GraspTask) -> str:
    """The tray, walls, camera, lights, gripper and ``MAX_SLOTS`` object slots."""
    cam_pos, cam_quat = camera_pose(np.zeros(3))
    w = TRAY_HALF_M + 0.005
    walls = "".join(
        f'<geom name="wall_{n}" type="box" size="{sx} {sy} 0.015" pos="{x} {y} 0.015" '
        f'rgba="0.45 0.35 0.25 1"/>'
        for n, sx, sy, x, y in (
            ("n", w, 0.005, 0, w),
            ("s", w, 0.005, 0, -w),
            ("e", 0.005, w, w, 0),
            ("w", 0.005, w, -w, 0),
        )
    )
    slots = "".join(
        f'<body name="obj{i}" pos="{0.1 * i} {PARK_Y_M} 0"><freejoint name="obj{i}"/>'
        + "".join(
            f'<geom name="obj{i}_p{j}" type="box" size="0.01 0.01 0.01" density="500"/>'
            for j in range(ko.MAX_PARTS)
        )
        + "</body>"
        for i in range(MAX_SLOTS)
    )
    z0 = task.start_height_m
    fo = FINGER_OPEN_M
    return f"""
<mujoco model="kuka_grasp_fast">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{PHYSICS_TIMESTEP_S}" integrator="implicitfast"/>
  <visual><global offwidth="640" offheight="480"/></visual>
  <default><geom friction="1 0.005 0.0001" solref="0.01 1" solimp="0.95 0.99 0.001"/></default>
  <worldbody>
    <light name="top" pos="0 0 1.2" dir="0 0 -1" directional="true" diffuse="0.7 0.7 0.7"
           ambient="0.25 0.25 0.25"/>
    <light name="side" pos="0.5 -0.5 0.8" dir="-0.5 0.5 -0.8" diffuse="0.3 0.3 0.3"/>
    <camera name="{CAMERA}" pos="{_vec(cam_pos)}" quat="{_vec(cam_quat)}" fovy="{CAMERA_FOVY_DEG}"/>
    <!-- The tray floor is a plane: plane contacts give resting cylinders and boxes several
         contact points (a box floor gives a lying cylinder one, and it rolls away). -->
    <geom name="tray" type="plane" size="0.6 0.6 0.6" rgba="0.75 0.7 0.6 1"/>
    {walls}
    <body name="gripper" pos="0 0 0" gravcomp="1">
      <joint name="grip_x" type="slide" axis="1 0 0" range="-0.13 0.13" damping="80"/>
      <joint name="grip_y" type="slide" axis="0 1 0" range="-0.13 0.13" damping="80"/>
      <joint name="grip_z" type="slide" axis="0 0 1" range="0 0.3" damping="80"/>
      <joint name="grip_yaw" type="hinge" axis="0 0 1" range="-3.2 3.2" damping="0.3"
             armature="0.005"/>
      <geom name="palm" type="box" size="0.015 0.075 0.008" pos="0 0 0.078" mass="0.3"
            rgba="0.3 0.3 0.32 1"/>
      <geom name="wrist" type="cylinder" size="0.012 0.02" pos="0 0 0.106" mass="0.05"
            contype="0" conaffinity="0" rgba="0.85 0.45 0.1 1"/>
      <site name="grasp" pos="0 0 0.015" size="0.004"/>
      <body name="finger_left" gravcomp="1">
        <joint name="finger_left" type="slide" axis="0 1 0" range="0 {fo}" damping="45"/>
        <geom name="finger_left" type="box" size="0.012 0.005 0.035" pos="0 0.005 0.035"
              mass="0.03" friction="1.2 0.01 0.001" condim="4" rgba="0.15 0.15 0.15 1"/>
      </body>
      <body name="finger_right" gravcomp="1">
        <joint name="finger_right" type="slide" axis="0 -1 0" range="0 {fo}" damping="45"/>
        <geom name="finger_right" type="box" size="0.012 0.005 0.035" pos="0 -0.005 0.035"
              mass="0.03" friction="1.2 0.01 0.001" condim="4" rgba="0.15 0.15 0.15 1"/>
      </body>
    </body>
    {slots}
  </worldbody>
  <contact><exclude body1="finger_left" body2="finger_right"/></contact>
  <actuator>
    <position name="grip_x" joint="grip_x" kp="4000" forcerange="-60 60"/>
    <position name="grip_y" joint="grip_y" kp="4000" forcerange="-60 60"/>
    <position name="grip_z" joint="grip_z" kp="4000" forcerange="-40 40"/>
    <position name="grip_yaw" joint="grip_yaw" kp="4" forcerange="-2 2"/>
    <position name="finger_left" joint="finger_left" kp="1500" forcerange="-12 12"/>
    <position name="finger_right" joint="finger_right" kp="1500" forcerange="-12 12"/>
  </actuator>
  <keyframe>
    <key name="start" qpos="0 0 {z0} 0 {fo} {fo}{" 0 0 0 1 0 0 0" * MAX_SLOTS}"
         ctrl="0 0 {z0} 0 {fo} {fo}"/>
  </keyframe>
</mujoco>"""


class KukaGraspBase(gym.Env[np.ndarray, Any], ABC):
    """The task logic both twins share: episode bookkeeping, the height hack, the action
    contract, object choice and layout, DR sampling and the lift check. A twin supplies the
    physics behind a handful of hooks."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}  # noqa: RUF012
    # Set by each twin's constructor.
    model: mujoco.MjModel
    data: mujoco.MjData
    slots: tuple[ko.Slot, ...]

    def __init__(
        self,
        actions: str,
        dr: str | DRConfig,
        objects: str,
        image_size: int,
        max_episode_steps: int | None,
        task: GraspTask | None,
        render_mode: str | None,
    ) -> None:
        self.task = task or GraspTask()
        self.action_space = action_space_for(actions)
        if image_size not in IMAGE_SIZES:
            raise ConfigError(f"image_size {image_size} not one of {list(IMAGE_SIZES)}")
        if render_mode not in (None, "rgb_array"):
            raise UnknownNameError("render_mode", str(render_mode), ["rgb_array"])
        steps = self.task.descent_steps if max_episode_steps is None else max_episode_steps
        if not isinstance(steps, int) or isinstance(steps, bool) or steps < 1:
            raise ConfigError(f"max_episode_steps {steps!r} must be an integer >= 1")
        self.catalog = ko.catalog(objects)  # validates the split name
        self.objects = objects
        self.actions = actions
        self.dr_config = load_preset(dr)
        self.render_mode = render_mode
        self.max_episode_steps = steps
        self.obs_mode = "pixels"
        self.control_dt_s = CONTROL_DT_S
        self.decoder = GraspActionDecoder(
            actions == "discrete", self.task.xy_step_m, self.task.yaw_step_rad
        )
        self.builder = pixel_builder(image_size)
        self.observation_space = gym.spaces.Box(0, 255, (image_size, image_size, 3), dtype=np.uint8)
        self.privileged_space = gym.spaces.Box(
            -np.inf, np.inf, (len(PRIVILEGED_FIELDS),), dtype=np.float32
        )
        self.actuation = GraspActuation()
        self._image_size = image_size
        self._target = np.zeros(4)  # x, y, z, yaw of the gripper target (tray frame)
        self._live: list[int] = []  # catalogue indices of the objects in the live slots
        self._half_heights = np.zeros(0)
        self._steps = 0
        self._done = False
        self._success = False
        self._distance_m = math.nan
        self._obs = np.zeros((image_size, image_size, 3), dtype=np.uint8)
        self.dr_params: dict[str, Any] = {}

    # ---- gymnasium API ---------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        rng = self.np_random
        self.dr_params = self._sample_dr(rng)
        self.actuation.configure(self.dr_params["actuation"])
        self.actuation.reset()
        t = self.task
        n = int(rng.integers(t.min_objects, t.max_objects + 1))
        chosen = rng.choice(len(self.catalog), size=n, replace=False)
        if options and "objects" in options:  # scripted scenes: these catalogue indices
            chosen = self._check_objects(options["objects"])
            n = len(chosen)
        self._live = [int(i) for i in chosen]
        obj = self.dr_params["object"]
        scale = float(obj["size_scale"])
        self._half_heights = self.catalog.half_height_m[chosen] * scale
        start = rng.uniform(-t.start_jitter_m, t.start_jitter_m, 2)
        self._target[:] = (start[0], start[1], t.start_height_m, 0.0)
        centres, clear = ko.sample_layout(
            rng, self.catalog.radius_xy_m[chosen] * scale, t.spawn_half_m
        )
        lim = t.spawn_half_m
        centres = np.clip(centres + obj["init_xy_offset_m"], -lim, lim)
        yaws = rng.uniform(-math.pi, math.pi, n)
        self._reset_scene(rng, chosen, obj, centres, yaws, clear)
        self._steps = 0
        self._done = self._success = False
        self._distance_m = self.nearest_object_xy_m()
        self._obs = self._pixels()
        info = {"dr": self.dr_params, "is_success": False}
        info[PRIVILEGED_INFO_KEY] = self.privileged_state()
        return self._obs, info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._done:  # past the end: nothing moves; the episode's outcome is repeated
            return self._obs, 0.0, True, False, self._info()
        move = self.actuation(self.decoder.decode(action), self.np_random)
        t = self.task
        tgt = self._target
        lim = t.workspace_half_m
        tgt[0] = min(max(tgt[0] + move[0], -lim), lim)
        tgt[1] = min(max(tgt[1] + move[1], -lim), lim)
        tgt[2] = max(tgt[2] - t.descent_m_per_step, t.bottom_height_m)  # the height hack
        tgt[3] = min(max(tgt[3] + move[2], -math.pi / 2), math.pi / 2)
        self._track_target()
        self._steps += 1
        self._distance_m = self.nearest_object_xy_m()
        reward = 0.0
        if tgt[2] <= t.bottom_height_m or self._steps >= self.max_episode_steps:
            self._close_and_lift()
            heights = self.object_positions()[:, 2]
            self._success = bool(np.any(heights > t.lift_success_m))
            self._done = True
            reward = float(self._success)
        self._obs = self._pixels()
        return self._obs, reward, self._done, False, self._info()

    # ---- task helpers (public for tests and scripted policies) ------------------------------
    @property
    def steps(self) -> int:
        return self._steps

    def live_objects(self) -> list[ko.ObjectSpec]:
        return [self.catalog.objects[i] for i in self._live]

    def nearest_object_xy_m(self) -> float:
        """Horizontal distance from the gripper centre to the closest object centre."""
        pos = self.object_positions()
        d = pos[:, :2] - self.gripper_pose()[:2]
        return float(np.sqrt(np.min(np.einsum("ij,ij->i", d, d))))

    def target_pose(self) -> np.ndarray:
        """(4,) where the gripper is commanded to be: x, y, z, yaw (tray frame)."""
        return self._target.copy()

    def privileged_state(self) -> np.ndarray:
        """(len(PRIVILEGED_FIELDS),) float32, see ``PRIVILEGED_FIELDS``: the target pose, the
        episode's progress and every slot's object relative to the target."""
        out = np.zeros(len(PRIVILEGED_FIELDS), dtype=np.float32)
        tgt = self._target
        s = PRIVILEGED_SCALE_M
        out[:4] = (tgt[0] / s, tgt[1] / s, tgt[2] / s, tgt[3])
        out[4] = self._steps / self.max_episode_steps
        pos = self.object_positions() if self._live else np.zeros((0, 3))
        slots = out[5:].reshape(MAX_SLOTS, 4)
        slots[: len(pos), 0] = 1.0
        slots[: len(pos), 1] = (pos[:, 0] - tgt[0]) / s
        slots[: len(pos), 2] = (pos[:, 1] - tgt[1]) / s
        slots[: len(pos), 3] = pos[:, 2] / s
        return out

    def _info(self) -> dict[str, Any]:
        return {
            "is_success": self._success,
            "distance_m": self._distance_m,
            "n_objects": len(self._live),
            PRIVILEGED_INFO_KEY: self.privileged_state(),
        }

    def _write_objects(self, chosen: np.ndarray, obj: dict[str, Any]) -> None:
        """Write the chosen catalog objects (with the episode's object DR) into the first slots;
        ``mj_setConst`` then refits solver weights to the new masses (it rewinds qpos)."""
        m = self.model
        s, mass, mu = float(obj["size_scale"]), float(obj["mass_scale"]), float(obj["friction"])
        for k, slot in enumerate(self.slots[: len(chosen)]):
            ko.write_object(m, slot, self.catalog, int(chosen[k]), s, mass, mu)
        mujoco.mj_setConst(m, self.data)

    # ---- hooks --------------------------------------------------------------------------------
    @abstractmethod
    def _sample_dr(self, rng: np.random.Generator) -> dict[str, Any]:
        """Draw every DR category (shared samplers, shared order) and apply the model ones."""

    @abstractmethod
    def _reset_scene(
        self,
        rng: np.random.Generator,
        chosen: np.ndarray,
        obj: dict[str, Any],
        centres_m: np.ndarray,
        yaws_rad: np.ndarray,
        clear: bool,
    ) -> None:
        """Write the chosen objects into the slots, put the gripper at the target, settle."""

    @abstractmethod
    def _track_target(self) -> None:
        """One control period of physics with the gripper driven to ``self._target``."""

    @abstractmethod
    def _close_and_lift(self) -> None:
        """Close the gripper where it is, lift to ``task.lift_to_m`` and hold."""

    @abstractmethod
    def _pixels(self) -> np.ndarray:
        """The (size, size, 3) uint8 observation."""

    @abstractmethod
    def object_positions(self) -> np.ndarray:
        """(k, 3) centres of the live objects, tray frame (z above the tray floor)."""

    @abstractmethod
    def gripper_pose(self) -> np.ndarray:
        """(4,) true x, y, z (fingertips above the tray floor) and yaw, tray frame."""

    @abstractmethod
    def set_object_pose(self, slot: int, xy_m: tuple[float, float], yaw_rad: float = 0.0) -> None:
        """Move live object ``slot`` to rest at ``xy_m`` (scripted tests and demos)."""

    def _check_objects(self, objects: Any) -> np.ndarray:
        idx = np.asarray(objects)
        size = len(self.catalog)
        if (
            idx.ndim != 1
            or not 1 <= len(idx) <= MAX_SLOTS
            or idx.dtype.kind not in "iu"
            or len(set(idx.tolist())) != len(idx)
            or np.any((idx < 0) | (idx >= size))
        ):
            raise ConfigError(
                f"options['objects'] {objects!r} must be 1 to {MAX_SLOTS} distinct indices "
                f"in [0, {size - 1}] of the {self.objects!r} object set"
            )
        return idx.astype(np.intp)

    def _check_slot(self, slot: int) -> None:
        if not 0 <= slot < len(self._live):
            raise ConfigError(f"object slot {slot} not in [0, {len(self._live) - 1}]")


class KukaGraspFastEnv(KukaGraspBase):
    """The seed project's grasping task on a floating gripper (see the module docstring)."""

    def __init__(
        self,
        actions: str = "discrete",
        dr: str | DRConfig = "default",
        objects: str = "train",
        image_size: int = 48,
        max_episode_steps: int | None = None,
        task: GraspTask | None = None,
        render_mode: str | None = None,
        render_width: int = 320,
        render_height: int = 240,
        spec: Any = None,  # accepted (and unused) so callers can pass the arm spec to every env
    ) -> None:
        super().__init__(actions, dr, objects, image_size, max_episode_steps, task, render_mode)
        self.frame_skip = round(CONTROL_DT_S / PHYSICS_TIMESTEP_S)
        self.model = mujoco.MjModel.from_xml_string(build_fast_mjcf(self.task))
        ko.prepare_model(self.model)
        apply_pixel_settings(self.model)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.slots = tuple(
            ko.Slot.from_names(m, f"obj{i}", [f"obj{i}_p{j}" for j in range(ko.MAX_PARTS)])
            for i in range(MAX_SLOTS)
        )
        self._gq = np.array([m.joint(j).qposadr[0] for j in GRIPPER_JOINTS], dtype=np.intp)
        self._key = m.key("start").id
        self.ids = ModelIds(
            arm_bodies=np.array([m.body(b).id for b in GRIPPER_BODIES], dtype=np.intp),
            arm_dofs=np.array([m.joint(j).dofadr[0] for j in GRIPPER_JOINTS], dtype=np.intp),
            servo_actuators=np.array([m.actuator(j).id for j in GRIPPER_JOINTS], dtype=np.intp),
            colour_geoms=np.array([m.geom(g).id for g in COLOUR_GEOMS], dtype=np.intp),
            cube_geom=-1,  # objects are slots, written by ``kuka_objects`` with the object params
            cube_body=-1,
            cameras=np.arange(m.ncam, dtype=np.intp),
            lights=np.arange(m.nlight, dtype=np.intp),
        )
        self.randomizer = DomainRandomizer(m, self.ids, self.dr_config)
        self._render_wh = (render_width, render_height)
        self._pixel_renderer: FastRenderer | None = None
        self._frame_renderer: FastRenderer | None = None

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._frame_renderer is None:
            self._frame_renderer = FastRenderer(self.model, *self._render_wh)
        return self._frame_renderer.render(self.data, CAMERA)

    def close(self) -> None:
        for r in (self._pixel_renderer, self._frame_renderer):
            if r is not None:
                r.close()
        self._pixel_renderer = self._frame_renderer = None

    def restore_nominal(self) -> None:
        """Put every DR-randomised model parameter back to its nominal, bit for bit."""
        self.randomizer.restore_nominal()

    def gripper_pose(self) -> np.ndarray:
        return self.data.qpos[self._gq].copy()

    def object_positions(self) -> np.ndarray:
        return np.array([self.data.xpos[self.slots[k].body] for k in range(len(self._live))])

    def set_object_pose(self, slot: int, xy_m: tuple[float, float], yaw_rad: float = 0.0) -> None:
        self._check_slot(slot)
        h = float(self._half_heights[slot])
        ko.place(self.data, self.slots[slot], (xy_m[0], xy_m[1], h + 0.001), yaw_rad)
        mujoco.mj_forward(self.model, self.data)
        self._distance_m = self.nearest_object_xy_m()
        self._obs = self._pixels()

    # ---- hooks --------------------------------------------------------------------------------
    def _sample_dr(self, rng: np.random.Generator) -> dict[str, Any]:
        params = self.randomizer.sample(rng)
        self.randomizer.apply(params)
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
        self._write_objects(chosen, obj)  # first: it rewinds qpos
        mujoco.mj_resetDataKeyframe(m, d, self._key)
        d.qpos[self._gq] = self._target
        d.ctrl[:4] = self._target
        for k, slot in enumerate(self.slots):
            if k < len(chosen):
                # the stacked fallback drops later objects from above the others
                z = self._half_heights[k] + (0.001 if clear else 0.07 * k + 0.001)
                ko.place(d, slot, (centres_m[k, 0], centres_m[k, 1], z), float(yaws_rad[k]))
            else:
                ko.park(m, d, slot, (0.3 * k, PARK_Y_M))
        mujoco.mj_forward(m, d)
        mujoco.mj_step(m, d, nstep=SETTLE_STEPS if clear else STACKED_SETTLE_STEPS)

    def _track_target(self) -> None:
        self.data.ctrl[:4] = self._target
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)

    def _close_and_lift(self) -> None:
        d, m = self.data, self.model
        d.ctrl[4:6] = 0.0
        mujoco.mj_step(m, d, nstep=CLOSE_STEPS)
        z0 = float(self._target[2])
        for k in range(1, LIFT_CHUNKS + 1):  # a ramp: a step in the target would fling objects
            self._target[2] = z0 + (self.task.lift_to_m - z0) * k / LIFT_CHUNKS
            d.ctrl[2] = self._target[2]
            mujoco.mj_step(m, d, nstep=LIFT_CHUNK_STEPS)
        mujoco.mj_step(m, d, nstep=HOLD_STEPS)

    def _pixels(self) -> np.ndarray:
        if self._pixel_renderer is None:
            size = self._image_size
            self._pixel_renderer = FastRenderer(self.model, size, size)
        return self._pixel_renderer.render(self.data, CAMERA)


__all__ = [
    "ACTION_MODES",
    "ACTION_NAMES",
    "CAMERA",
    "CONTROL_DT_S",
    "DISCRETE_ACTIONS",
    "IGNORED_DR_KEYS",
    "PRIVILEGED_FIELDS",
    "PRIVILEGED_INFO_KEY",
    "GraspActionDecoder",
    "GraspTask",
    "KukaGraspBase",
    "KukaGraspFastEnv",
    "action_space_for",
    "build_fast_mjcf",
    "nearest_object_offset",
    "privileged_teacher_action",
]
