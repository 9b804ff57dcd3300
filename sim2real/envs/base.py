"""The shared 3-DOF arm environment; a task is one small class that plugs into it.

Per control step: normalised action → ``ActionDecoder`` (joint-target deltas) → servo actuation
layer (noise, latency, dead band, speed limit, quantisation) → MuJoCo (``frame_skip`` physics
steps) → sensor models (servo readings, stereo-shaped position noise, delay) →
``ObservationBuilder``. The deploy loop uses the same decoder and builder on real readings.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np

from hardware.safety import SafetyFilter
from hardware.spec import ArmSpec, load_spec
from sim2real.actuation import ServoActuation
from sim2real.envs.contract import DeployContract
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.model import ArmTwin, RigSpec, build_model
from sim2real.observation import (
    COMMAND_FIELDS,
    ActionDecoder,
    ObservationBuilder,
    ObsField,
    command_readings,
)
from sim2real.randomization import DomainRandomizer, ModelIds, load_preset
from sim2real.randomization.config import DRConfig
from sim2real.randomization.sensing import SensorModel
from sim2real.rendering import FastRenderer


# ---- rewards: one registry, vectorised so HER's compute_reward can call them on batches ------
def _distance_reward(d_m: np.ndarray, success: np.ndarray) -> np.ndarray:
    """-5·d plus a bonus: pays for the last centimetre (NOTES: -d² is flat near the target)."""
    return -5.0 * d_m + 1.0 * success


def _squared_reward(d_m: np.ndarray, success: np.ndarray) -> np.ndarray:
    """The seed project's shape: -(distance²) scaled, plus a success bonus."""
    return -100.0 * d_m * d_m + 1.0 * success


def _sparse_reward(d_m: np.ndarray, success: np.ndarray) -> np.ndarray:
    """0 on success, -1 otherwise (HER's usual setting)."""
    return success * 1.0 - 1.0


REWARDS: dict[str, Callable[[Any, Any], Any]] = {
    "distance": _distance_reward,
    "squared": _squared_reward,
    "sparse": _sparse_reward,
}
OBS_MODES: tuple[str, ...] = ("state", "goal", "pixels")
# ``reset(options={"start": ...})``: "default" is the task's own start; "held" (tasks that list
# it in ``start_modes``) starts with the object already in the gripper, a training curriculum.
START_DEFAULT, START_HELD = "default", "held"


@dataclass(frozen=True)
class Sensed:
    """One step's sensor readings (what a policy may know), all in the base frame."""

    joints_rad: np.ndarray  # (n_actuators_used,)
    ee_m: np.ndarray  # (3,)
    points_m: np.ndarray  # (k, 3) task points (target, cube, ...)
    blind_s: np.ndarray  # (k,) time since each task point was last seen (0: seen now)


class Task(ABC):
    """Target sampling, reward and success of one mission; the env does everything else."""

    name: ClassVar[str]
    scene: ClassVar[str]
    uses_gripper: ClassVar[bool] = False
    success_threshold_m: ClassVar[float] = 0.01
    default_reward: ClassVar[str] = "distance"
    n_points: ClassVar[int] = 1  # rows of true_points()
    start_modes: ClassVar[tuple[str, ...]] = (START_DEFAULT,)  # what reset's "start" accepts
    # Observe the commanded pose too (``COMMAND_FIELDS``): opt-in, so that a task's tuned presets
    # and measured figures stay valid until it is re-measured with them.
    command_fields: ClassVar[bool] = False
    # The gripper can hide the task points (a cube in its fingers): the sensor model drops them
    # out near the tool and reports how long they have been blind (``Sensed.blind_s``).
    occludable: ClassVar[bool] = False
    # What the task needs outside the simulator (``sim2real.envs.contract``); None: sim only.
    contract: ClassVar[type[DeployContract] | None] = None

    @abstractmethod
    def reset(self, env: Arm3Env, rng: np.random.Generator) -> None:
        """Place the task's objects (target, cube, path) for a new episode."""

    def held_start(
        self, env: Arm3Env, rng: np.random.Generator, height_m: float | None
    ) -> np.ndarray:
        """Put the arm at the object with it grasped (after ``reset``); returns the actuator
        targets that hold it. Only tasks with ``START_HELD`` in ``start_modes`` have one."""
        raise ConfigError(f"task {self.name!r} has no {START_HELD!r} start")

    def after_step(self, env: Arm3Env) -> None:  # noqa: B027 - optional hook
        """Advance task state (a moving target) after physics."""

    @abstractmethod
    def true_points(self, env: Arm3Env) -> np.ndarray:
        """(k, 3) positions the cameras observe for this task, in the base frame."""

    @abstractmethod
    def goals(self, env: Arm3Env, sensed: Sensed) -> tuple[np.ndarray, np.ndarray]:
        """(achieved_goal, desired_goal) as the policy sees them (sensed values)."""

    @abstractmethod
    def true_goals(self, env: Arm3Env) -> tuple[np.ndarray, np.ndarray]:
        """(achieved, desired) ground truth: success and reward are judged on these."""

    def obs_fields(
        self, n_joint_readings: int, n_actions: int, goal_conditioned: bool
    ) -> tuple[ObsField, ...]:
        fields = [
            ObsField("joint_pos", n_joint_readings, "rad", "servo readings (joints, then gripper)"),
            ObsField("ee_pos", 3, "m", "end-effector position estimate, base frame"),
            *self.extra_fields(),
        ]
        if not goal_conditioned:
            fields += [
                ObsField("goal_pos", 3, "m", "desired goal estimate, base frame"),
                ObsField("goal_delta", 3, "m", "desired goal minus achieved goal"),
            ]
        # The command side: what was sent (joint_target − joint_pos is the motion still in the
        # pipe, which is what a policy needs to stay stable under servo and camera lag).
        fields.append(
            ObsField("joint_target", n_joint_readings, "rad", "last commanded joint targets")
        )
        if self.command_fields:
            fields += COMMAND_FIELDS[:1] if goal_conditioned else COMMAND_FIELDS
        fields.append(ObsField("prev_action", n_actions, "1", "last normalised action"))
        return tuple(fields)

    def extra_fields(self) -> tuple[ObsField, ...]:
        return ()

    def extra_readings(self, env: Arm3Env, sensed: Sensed) -> dict[str, np.ndarray]:
        return {}

    def shaping(self, env: Arm3Env) -> float:
        """Extra dense reward outside the goal-based part (not seen by HER)."""
        return 0.0

    def success_from_distance(self, env: Arm3Env, distance_m: float) -> bool:
        """Success given the true achieved-to-desired distance (tasks may judge differently)."""
        return distance_m < self.success_threshold_m

    def is_success(self, env: Arm3Env) -> bool:
        achieved, desired = self.true_goals(env)
        return self.success_from_distance(env, float(np.linalg.norm(achieved - desired)))


TASKS: dict[str, type[Task]] = {}


def register_task(cls: type[Task]) -> type[Task]:
    """Class decorator: a new mission is one file with one decorated Task subclass."""
    TASKS[cls.name] = cls
    return cls


class Arm3Env(gym.Env[Any, np.ndarray]):
    """The hobby arm in MuJoCo with domain randomisation, for any registered ``Task``."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}  # noqa: RUF012

    def __init__(
        self,
        task: str = "reach",
        dr: str | DRConfig = "default",
        obs_mode: str = "state",
        reward: str | None = None,
        control_hz: float = 20.0,
        max_episode_steps: int = 50,
        max_delta_rad: float = 0.1,
        image_size: int = 84,
        camera: str = "cam_left",
        spec: ArmSpec | str | None = None,
        rig: RigSpec | None = None,
        render_mode: str | None = None,
        render_width: int = 640,
        render_height: int = 480,
        safety_filter: bool = False,
    ) -> None:
        if task not in TASKS:
            raise UnknownNameError("task", task, TASKS)
        if obs_mode not in OBS_MODES:
            raise UnknownNameError("obs_mode", obs_mode, OBS_MODES)
        self.task = TASKS[task]()
        reward = reward or self.task.default_reward
        if reward not in REWARDS:
            raise UnknownNameError("reward", reward, REWARDS)
        if render_mode not in (None, "rgb_array"):
            raise UnknownNameError("render_mode", str(render_mode), ["rgb_array"])
        if not 1.0 <= control_hz <= 200.0:
            raise ConfigError(f"control_hz {control_hz} not in [1, 200]")
        if max_episode_steps < 1:
            raise ConfigError(f"max_episode_steps {max_episode_steps} must be >= 1")
        if image_size not in (48, 64, 84, 96, 128):
            raise ConfigError(f"image_size {image_size} not one of [48, 64, 84, 96, 128]")
        self.spec_arm = spec if isinstance(spec, ArmSpec) else load_spec(spec)
        self.rig = rig or RigSpec()
        self.rig.camera(camera)  # validates the name
        self.dr_config = load_preset(dr)
        self.obs_mode, self.reward_name = obs_mode, reward
        self._reward_fn = REWARDS[reward]
        self.render_mode = render_mode
        self.max_episode_steps = max_episode_steps

        self.model = build_model(self.spec_arm, self.task.scene, self.rig)
        self.data = mujoco.MjData(self.model)
        self.control_dt_s = 1.0 / control_hz
        self.frame_skip = max(1, round(self.control_dt_s / self.model.opt.timestep))
        self.ids = ModelIds.from_model(self.model, self.spec_arm.joint_names)
        self.randomizer = DomainRandomizer(self.model, self.ids, self.dr_config)

        spec = self.spec_arm
        n_j = spec.n_joints
        self.twin = ArmTwin(self.model, spec)
        self._qadr = self.twin.qadr
        self._tool_site = self.twin.tool_site
        self.decoder = ActionDecoder(spec, max_delta_rad, use_gripper=self.task.uses_gripper)
        # Train as deployed: the host's safety filter (limits, the per-step clamp, gripper
        # included, and the workspace guard) between the decoded targets and the servos, as
        # ``Arm.command`` puts it on every backend. Without it a pick policy learns to snap the
        # gripper shut in one step and to push the tool below the guard's floor.
        self._safety = SafetyFilter(spec) if safety_filter else None
        self._n_readings = n_j + (1 if self.task.uses_gripper else 0)
        self._n_act = self.decoder.n_actions
        self.actuation = ServoActuation(spec, self.control_dt_s, n_j)
        cam0 = self.rig.cameras[0]
        T = cam0.base_T_cam()
        self.sensors = SensorModel(
            self._n_readings,
            spec.servo.resolution_rad,
            T[:3, :3],
            T[:3, 3],
            cam0.focal_px,
            self.rig.baseline_m,
        )
        self.builder = ObservationBuilder(
            self.task.obs_fields(self._n_readings, self._n_act, obs_mode == "goal")
        )

        self.action_space = gym.spaces.Box(-1.0, 1.0, (self._n_act,), dtype=np.float32)
        vec = gym.spaces.Box(-np.inf, np.inf, (self.builder.size,), dtype=np.float32)
        goal = gym.spaces.Box(-np.inf, np.inf, (3,), dtype=np.float32)
        self.observation_space: gym.spaces.Space[Any]
        if obs_mode == "goal":
            self.observation_space = gym.spaces.Dict(
                {"observation": vec, "achieved_goal": goal, "desired_goal": goal}
            )
        elif obs_mode == "pixels":
            self.observation_space = gym.spaces.Box(
                0, 255, (image_size, image_size, 3), dtype=np.uint8
            )
        else:
            self.observation_space = vec

        self._camera = camera
        self._image_size = image_size
        self._pixel_renderer: FastRenderer | None = None
        self._frame_renderer: FastRenderer | None = None
        self._render_wh = (render_width, render_height)
        self._targets = spec.actuator_home_rad.copy()
        self._sent = self._targets.copy()
        self._prev_action = np.zeros(self._n_act)
        self._steps = 0
        self.dr_params: dict[str, Any] = {}
        self._points_buf = np.zeros((1 + self.task.n_points, 3))
        self._readings_buf = np.zeros(self._n_readings)  # sense(): the sensors copy it
        self._not_blind = np.zeros(self.task.n_points)
        # Pixel variants report the true state in info["privileged_state"], for training-only
        # critics and teachers (sim2real.train); the observation never holds it.
        n_priv = self._n_readings + len(self._targets) + 3 * (1 + self.task.n_points)
        self.privileged_space = (
            gym.spaces.Box(-np.inf, np.inf, (n_priv,), dtype=np.float32)
            if obs_mode == "pixels"
            else None
        )

    # ---- gymnasium API ---------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        rng = self.np_random
        self.dr_params = self.randomizer.sample(rng)
        self.randomizer.apply(self.dr_params)
        self.actuation.configure(self.dr_params["actuation"])
        self.sensors.configure(self.dr_params["sensing"])
        self.sensors.reset()

        mujoco.mj_resetData(self.model, self.data)
        spec = self.spec_arm
        q0 = np.clip(
            spec.home_rad + rng.uniform(-0.15, 0.15, spec.n_joints), spec.lower_rad, spec.upper_rad
        )
        self._targets = spec.actuator_home_rad.copy()
        self._targets[: spec.n_joints] = q0
        self._sent = self._targets.copy()
        self._set_arm_qpos(q0)
        self.actuation.reset(q0)
        self._write_ctrl(q0)
        self._prev_action = np.zeros(self._n_act)
        self._steps = 0
        self.task.reset(self, rng)
        start, height_m = self._start_option(options)
        if start == START_HELD:
            self._start_held(rng, height_m)
        mujoco.mj_forward(self.model, self.data)
        obs = self._observe()
        info = {"dr": self.dr_params, "is_success": self.task.is_success(self), "start": start}
        if self.privileged_space is not None:
            info["privileged_state"] = self.privileged_state()
        return obs, info

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        a = np.minimum(np.maximum(action, -1.0), 1.0)
        self._targets = self.decoder.decode_clipped(a, self._targets)
        n = self.spec_arm.n_joints
        if self._safety is None:
            self._sent = self._targets
        else:
            self._sent = self._safety.filter(self._targets, self._sent)
        joint_ctrl = self.actuation(self._sent[:n], self.np_random)
        self._write_ctrl(joint_ctrl)
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        self.task.after_step(self)
        self._prev_action = a
        self._steps += 1
        obs = self._observe()
        achieved, desired = self.task.true_goals(self)
        diff = achieved - desired
        d = math.sqrt(diff @ diff)
        success = self.task.success_from_distance(self, d)
        reward = float(self._reward_fn(d, d < self.task.success_threshold_m))
        if self.obs_mode != "goal":  # HER recomputes rewards from goals alone
            reward += self.task.shaping(self)
        truncated = self._steps >= self.max_episode_steps
        info: dict[str, Any] = {"is_success": success, "distance_m": d}
        if self.privileged_space is not None:
            info["privileged_state"] = self.privileged_state()
        return obs, reward, False, truncated, info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._frame_renderer is None:
            self._frame_renderer = FastRenderer(self.model, *self._render_wh)
        return self._frame_renderer.render(self.data, self._camera)

    def close(self) -> None:
        for r in (self._pixel_renderer, self._frame_renderer):
            if r is not None:
                r.close()
        self._pixel_renderer = self._frame_renderer = None

    # ---- helpers ---------------------------------------------------------------------------
    def _start_option(self, options: dict[str, Any] | None) -> tuple[str, float | None]:
        """``options["start"]`` (default "default") and ``options["held_height_m"]`` (None:
        the task samples one), validated against what this task offers."""
        opts = options or {}
        start = str(opts.get("start", START_DEFAULT))
        if start not in self.task.start_modes:
            raise UnknownNameError(
                f"start for task {self.task.name!r}", start, self.task.start_modes
            )
        height = opts.get("held_height_m")
        return start, None if height is None else float(height)

    def _start_held(self, rng: np.random.Generator, height_m: float | None) -> None:
        """The task grasps its object with real contacts; then the command side (targets, the
        servo model's lag state, the last action) is made to match, so the first observation
        reads as if the policy had been holding: joint deltas 0, gripper closed (-1)."""
        targets = self.task.held_start(self, rng, height_m)
        self._targets = np.array(targets, dtype=float)
        self._sent = self._targets.copy()
        self.actuation.reset(self._targets[: self.spec_arm.n_joints])
        self._write_ctrl(self._targets[: self.spec_arm.n_joints])
        self._prev_action = np.zeros(self._n_act)
        if self.task.uses_gripper:
            self._prev_action[-1] = -1.0  # the absolute gripper action that commands "closed"

    def restore_nominal(self) -> None:
        """Put every randomised model parameter back to its nominal, bit for bit."""
        self.randomizer.restore_nominal()

    def ee_position(self) -> np.ndarray:
        """True tool position (3,) in the base frame."""
        return self.data.site_xpos[self._tool_site]

    def joint_positions(self) -> np.ndarray:
        """True joint angles (n_joints,)."""
        return self.data.qpos[self._qadr]

    def gripper_angle_rad(self) -> float:
        return self.twin.gripper_rad(self.data)

    @property
    def steps(self) -> int:
        return self._steps

    def commanded_rad(self) -> np.ndarray:
        """The actuator targets last commanded (joints, then gripper): what the deploy loop
        knows it sent."""
        return self._targets

    def _gripper_target(self) -> float | None:
        return float(self._sent[-1]) if self.twin.has_gripper else None

    def _set_arm_qpos(self, q_rad: np.ndarray) -> None:
        self.twin.set_pose(self.data, q_rad, self._gripper_target())

    def _write_ctrl(self, joint_ctrl_rad: np.ndarray) -> None:
        self.twin.write_ctrl(self.data, joint_ctrl_rad, self._gripper_target())

    def privileged_state(self) -> np.ndarray:
        """True joint angles (and gripper), joint targets, then the tool and the task's points
        (m, world): no sensor model, no delay."""
        q = self.data.qpos[self._qadr]
        if self.task.uses_gripper:
            q = np.append(q, self.gripper_angle_rad())
        tool = self.data.site_xpos[self._tool_site]
        points = self.task.true_points(self).reshape(-1)
        return np.concatenate([q, self._targets, tool, points]).astype(np.float32)

    def sense(self) -> Sensed:
        rng = self.np_random
        q = self.data.qpos[self._qadr]
        if self.task.uses_gripper:  # joints, then the gripper: filled in place, not appended
            q_buf = self._readings_buf
            q_buf[:-1] = q
            q_buf[-1] = self.gripper_angle_rad()
            q = q_buf
        pts = self._points_buf
        pts[0] = self.data.site_xpos[self._tool_site]
        pts[1:] = self.task.true_points(self)
        joints, est = self.sensors.read(q, pts, rng)
        blind = self._not_blind
        if self.task.occludable:
            held, blind_steps = self.sensors.occlude(est[1:], pts[0], pts[1:], rng)
            est = np.concatenate([est[:1], held])
            blind = blind_steps * self.control_dt_s
        if self.sensors.delay_steps:
            joints, est, blind = self.sensors.delay(joints, est, blind)
        return Sensed(joints, est[0], est[1:], blind)

    def _observe(self) -> Any:
        if self.obs_mode == "pixels":
            return self._pixels()
        sensed = self.sense()
        achieved, desired = self.task.goals(self, sensed)
        readings = {
            "joint_pos": sensed.joints_rad,
            "joint_target": self._targets[: self._n_readings],
            "ee_pos": sensed.ee_m,
            "goal_pos": desired,
            "goal_delta": desired - achieved,
            "prev_action": self._prev_action,
            **self.task.extra_readings(self, sensed),
        }
        if self.task.command_fields:  # the goal env's layout has no target_goal_delta
            goal = None if self.obs_mode == "goal" else desired
            readings.update(command_readings(self.spec_arm, self._targets, goal))
        vec = self.builder.build(readings)
        if self.obs_mode == "goal":
            return {
                "observation": vec,
                "achieved_goal": achieved.astype(np.float32),
                "desired_goal": desired.astype(np.float32),
            }
        return vec

    def _pixels(self) -> np.ndarray:
        if self._pixel_renderer is None:
            self._pixel_renderer = FastRenderer(self.model, self._image_size, self._image_size)
        return self._pixel_renderer.render(self.data, self._camera)


class Arm3GoalEnv(Arm3Env):
    """Goal-conditioned variant (Dict observation) for HER; only it has ``compute_reward``,
    because SB3 treats any env with that method as a goal env."""

    def __init__(self, **kwargs: Any) -> None:
        kwargs.setdefault("reward", "sparse")
        if kwargs.setdefault("obs_mode", "goal") != "goal":
            raise ConfigError(f"Arm3GoalEnv needs obs_mode='goal', got {kwargs['obs_mode']!r}")
        super().__init__(**kwargs)

    def compute_reward(
        self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any
    ) -> np.ndarray:
        """Vectorised goal reward for HER (batches of goals)."""
        d = np.linalg.norm(np.asarray(achieved_goal) - np.asarray(desired_goal), axis=-1)
        return self._reward_fn(d, d < self.task.success_threshold_m).astype(np.float32)
