"""The shared 3-DOF arm environment; a task is one small class that plugs into it.

Per control step: normalised action → ``ActionDecoder`` (joint-target deltas) → servo actuation
layer (noise, latency, dead band, speed limit, quantisation) → MuJoCo (``frame_skip`` physics
steps) → sensor models (servo readings, stereo-shaped position noise, delay) →
``ObservationBuilder``. The deploy loop uses the same decoder and builder on real readings.

The layers around the physics run compiled (``sim2real.envs.fused``), one call each side of
``mj_step``: the same operations as the numpy models named above, which stay the reference that
tests hold the kernels to, bit for bit.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np

from hardware.safety import SafetyFilter
from hardware.spec import ArmSpec, load_spec
from sim2real.actuation import ServoActuation
from sim2real.envs import fused
from sim2real.envs.contract import DeployContract
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.model import ArmTwin, RigSpec, build_model
from sim2real.observation import (
    COMMAND_FIELDS,
    PIXELS_KEY,
    PROPRIO_FIELDS,
    PROPRIO_KEY,
    ActionDecoder,
    ObservationBuilder,
    ObsField,
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
# ``success_threshold_m`` overrides the task's own success distance within (0, this].
MAX_SUCCESS_THRESHOLD_M = 0.05
# ``reset(options={"start": ...})``: "default" is the task's own start; "held" (tasks that list
# it in ``start_modes``) starts with the object already in the gripper, a training curriculum.
START_DEFAULT, START_HELD = "default", "held"


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
    # out near the tool and reports how long they have been blind (``SensorModel.occlude``).
    occludable: ClassVar[bool] = False
    # What the task needs outside the simulator (``sim2real.envs.contract``); None: sim only.
    contract: ClassVar[type[DeployContract] | None] = None
    # The observed (achieved, desired) goal from the sensed readings, one of ``fused.GOAL_RULES``:
    # "tool_to_point" (the tool, the first point) or "object_to_goal" (the first point, the
    # grasp-aware estimate while the fingers hide it, and ``obs_aux[0]``).
    goal_rule: ClassVar[str] = "tool_to_point"
    # The grasp-aware estimate: a hidden object moves with the tool while the gripper reads this
    # far open of "closed" while commanded closed (``pick.holding``); blind times cap here. A
    # gripper that reads its command (``feedback: commanded``) cannot read a blocked close: it
    # holds when closed with the object's estimate within ``grasp_near_m`` of the tool's, or
    # hidden in fingers that held it (``pick.held_seen``).
    hold_margin_rad: ClassVar[float] = math.inf
    grasp_near_m: ClassVar[float] = 0.0
    # A sighting this far from the tool while the fingers hold the object is not the object
    # (``pick.cube_estimate``): the estimate stays with the tool.
    held_away_m: ClassVar[float] = math.inf
    blind_cap_s: ClassVar[float] = 0.0
    # ``shaping`` compiled into the observation's call (``fused.SHAPING_RULES``), fed by
    # ``shaping_ids``/``shaping_prm``, which the task keeps current; "none": ``shaping`` runs.
    shaping_rule: ClassVar[str] = "none"

    def placement(self, env: Arm3Env) -> dict[str, np.ndarray]:
        """This episode's objects in the deploy contract's format (``DeployContract.placement``:
        name → position, plus yaw or heading): a world that places objects replays the env's
        own episode, so env and deploy runs compare on the same placements."""
        raise NotImplementedError(f"task {self.name!r} does not report its placement")

    def __init__(self) -> None:
        # Vectors the compiled observation reads: row 0 the goal of "object_to_goal", row 1
        # the ``goal_vel`` field. A task writes them when they change.
        self.obs_aux = np.zeros((2, 3))
        self.shaping_ids = np.zeros(0, dtype=np.int32)
        self.shaping_prm = np.zeros(0)

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
        """Task fields after ``ee_pos``; each must be one of ``fused.FIELDS``."""
        return ()

    def shaping(self, env: Arm3Env) -> float:
        """Extra dense reward outside the goal-based part (not seen by HER)."""
        return 0.0

    # Values after the points in ``Arm3Env.privileged_state`` (``privileged_extra``), for a
    # privileged teacher that needs more of the truth than the points (pick: its lift goal).
    n_privileged_extra: ClassVar[int] = 0

    def privileged_extra(self, env: Arm3Env) -> np.ndarray:
        """(``n_privileged_extra``,) task truth for training-only teachers and critics."""
        return np.zeros(0)

    def success_from_distance(self, env: Arm3Env, distance_m: float) -> bool:
        """Success given the true achieved-to-desired distance (tasks may judge differently);
        the env's threshold: the task's own unless ``success_threshold_m`` was given."""
        return distance_m < env.success_threshold_m

    def is_success(self, env: Arm3Env) -> bool:
        achieved, desired = self.true_goals(env)
        return self.success_from_distance(env, float(np.linalg.norm(achieved - desired)))


TASKS: dict[str, type[Task]] = {}


def _check_success_threshold(value: Any) -> float:
    """A success distance in (0, ``MAX_SUCCESS_THRESHOLD_M``] m: a preset asking for 2 cm gets
    2 cm in training and in ``evaluate`` alike (the run records its env kwargs)."""
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    if not ok or not 0.0 < value <= MAX_SUCCESS_THRESHOLD_M:
        raise ConfigError(
            f"success_threshold_m must be a number in (0, {MAX_SUCCESS_THRESHOLD_M}], got {value!r}"
        )
    return float(value)


def _check_proprio(names: Any, obs_mode: str) -> tuple[str, ...]:
    """``proprio``: fields of ``PROPRIO_FIELDS`` beside a pixel observation, once each."""
    if isinstance(names, str) or not isinstance(names, Sequence):
        raise ConfigError(f"proprio must be a list of field names, got {names!r}")
    out = tuple(names)
    if out and obs_mode != "pixels":
        raise ConfigError(f"proprio {list(out)} needs obs_mode='pixels', got {obs_mode!r}")
    for name in out:
        if name not in PROPRIO_FIELDS:
            raise UnknownNameError("proprio field", str(name), PROPRIO_FIELDS)
    if len(set(out)) != len(out):
        raise ConfigError(f"proprio fields must be unique, got {list(out)}")
    return out


def privileged_true_size(spec: ArmSpec, task: type[Task] | Task) -> int:
    """How many leading values of ``Arm3Env.privileged_state`` are the simulator's truth (the
    readings' joints, the targets, the tool, the task's points, what the safety filter let
    through, the task's extras); the state observation follows."""
    n_points = 3 * (1 + task.n_points)
    return (
        spec.n_joints
        + int(task.uses_gripper)
        + 2 * spec.n_actuators
        + n_points
        + (task.n_privileged_extra)
    )


def register_task(cls: type[Task]) -> type[Task]:
    """Class decorator: a new mission is one file with one decorated Task subclass."""
    TASKS[cls.name] = cls
    return cls


_NOT_COPYABLE = (
    "{} cannot be copied or pickled (its compiled step reads views of its own MuJoCo "
    "buffers): make another with sim2real.envs.make(id, **kwargs) and reset it with the seed"
)


class Arm3Env(gym.Env[Any, np.ndarray]):
    """The hobby arm in MuJoCo with domain randomisation, for any registered ``Task``."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}  # noqa: RUF012

    def __deepcopy__(self, memo: dict[int, Any]) -> Arm3Env:
        """Refused (and pickling, ``__reduce_ex__``): the compiled step reads views of this env's
        MuJoCo buffers and its observation memory, and draws from a generator bound by address
        (``fused.RngBinding``); a copy's views would still read the original's arrays."""
        raise TypeError(_NOT_COPYABLE.format(type(self).__name__))

    def __reduce_ex__(self, protocol: Any) -> Any:
        raise TypeError(_NOT_COPYABLE.format(type(self).__name__))

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
        success_threshold_m: float | None = None,
        proprio: Sequence[str] = (),
        target_stand: bool = False,
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
        self.success_threshold_m = _check_success_threshold(
            self.task.success_threshold_m if success_threshold_m is None else success_threshold_m
        )
        self.proprio = _check_proprio(proprio, obs_mode)
        if not isinstance(target_stand, bool):
            raise ConfigError(f"target_stand must be true or false, got {target_stand!r}")
        self.spec_arm = spec if isinstance(spec, ArmSpec) else load_spec(spec)
        self.rig = rig or RigSpec()
        self.rig.camera(camera)  # validates the name
        self.dr_config = load_preset(dr)
        self.obs_mode, self.reward_name = obs_mode, reward
        self._reward_fn = REWARDS[reward]
        self.render_mode = render_mode
        self.max_episode_steps = max_episode_steps

        self.model = build_model(
            self.spec_arm, self.task.scene, self.rig, target_stand=target_stand
        )
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
        # readings that echo the command (``feedback: commanded``), slewed as the board slews
        # its output pulse: at the spec's speeds, the firmware's slew-rate limit
        speeds = [spec.servo.max_speed_rad_s] * n_j
        if spec.gripper is not None:
            speeds.append(spec.gripper.max_speed_rad_s)
        n_r = self._n_readings
        self.sensors = SensorModel(
            n_r,
            spec.servo.resolution_rad,
            T[:3, :3],
            T[:3, 3],
            cam0.focal_px,
            self.rig.baseline_m,
            commanded=~spec.actuator_measured[:n_r],
            slew_rad_per_step=np.array(speeds[:n_r]) * self.control_dt_s,
        )
        self.builder = ObservationBuilder(
            self.task.obs_fields(self._n_readings, self._n_act, obs_mode == "goal")
        )
        self._init_fused()

        self.action_space = gym.spaces.Box(-1.0, 1.0, (self._n_act,), dtype=np.float32)
        vec = gym.spaces.Box(-np.inf, np.inf, (self.builder.size,), dtype=np.float32)
        goal = gym.spaces.Box(-np.inf, np.inf, (3,), dtype=np.float32)
        self.observation_space: gym.spaces.Space[Any]
        if obs_mode == "goal":
            self.observation_space = gym.spaces.Dict(
                {"observation": vec, "achieved_goal": goal, "desired_goal": goal}
            )
        elif obs_mode == "pixels":
            image = gym.spaces.Box(0, 255, (image_size, image_size, 3), dtype=np.uint8)
            self.observation_space = image
            # The arm's own readings beside the frame, each through its state-observation model
            # (servo readings with bias, noise, quantisation and delay; what was commanded).
            layout = {f.name: f for f in self.builder.layout()}
            self._proprio_idx = np.array(
                [i for n in self.proprio for i in range(layout[n].start, layout[n].stop)],
                dtype=np.intp,
            )
            if self.proprio:
                readings = gym.spaces.Box(
                    -np.inf, np.inf, (len(self._proprio_idx),), dtype=np.float32
                )
                self.observation_space = gym.spaces.Dict({PIXELS_KEY: image, PROPRIO_KEY: readings})
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
        # Gymnasium's OrderEnforcing, in the env: the registered ids are made without that
        # wrapper (one Python layer less on every step), and step/render before the first reset
        # still raise ``ResetNeeded``
        self._needs_reset = True
        self.dr_params: dict[str, Any] = {}
        # Pixel variants report the true state in info["privileged_state"], for training-only
        # critics and teachers (sim2real.train); the observation never holds it. Its tail is the
        # state observation (``privileged_state``), so ``_observe`` senses in every mode.
        self._state_obs = np.zeros(self.builder.size, dtype=np.float32)
        n_priv = privileged_true_size(spec, self.task) + self.builder.size
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
        self._configure_fused()

        mujoco.mj_resetData(self.model, self.data)
        n_j = len(self._home_rad)
        q0 = self._home_rad + rng.uniform(-0.15, 0.15, n_j)
        q0 = np.minimum(np.maximum(q0, self._lo_rad), self._hi_rad)  # np.clip's bits, less cost
        self._targets = self._actuator_home_rad.copy()
        self._targets[:n_j] = q0
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
        obs, d, _ = self._observe(rng)
        success = self.task.success_from_distance(self, d)  # is_success's bits, d is its norm
        info = {"dr": self.dr_params, "is_success": success, "start": start}
        if self.privileged_space is not None:
            info["privileged_state"] = self.privileged_state()
        self._needs_reset = False
        return obs, info

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        if self._needs_reset:
            raise gym.error.ResetNeeded("Cannot call env.step() before calling env.reset()")
        action = np.asarray(action)
        if action.dtype != np.float32:  # a float32 action scales in float32, as numpy does
            action = action.astype(np.float64)
        a = np.empty_like(action)
        targets = np.empty_like(self._targets)
        act, servo, rng = self.actuation, self.actuation.servo, self.np_random
        # the command noise is drawn before the safety filter runs: it draws nothing
        noise = act.noise.take(rng) if act.noise_rad > 0 else self._no_noise
        cmd, max_delta = self._cmd, self._max_delta[action.dtype]
        if self._safety is None:  # decode → servo in one call
            fused.command(
                action, a, self._targets, targets, max_delta, cmd, noise, act.noise_rad,
                servo.applied_rad, servo.queue_rad, servo.head, self._ctrl,
            )  # fmt: skip
            self._sent = targets
        else:
            fused.decode(
                action, a, self._targets, targets, self._lo_rad, self._hi_rad, max_delta,
                self._decode_grip,
            )  # fmt: skip
            self._sent = self._safety.filter(targets, self._sent)
            fused.actuate(
                self._sent, noise, act.noise_rad, self._servo_prm, servo.applied_rad,
                servo.queue_rad, servo.head, self._ctrl, self._ctrl_grip,
            )  # fmt: skip
        self._targets = targets
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        if self._after_step:
            self.task.after_step(self)
        self._prev_action = a
        self._steps += 1
        obs, d, shaped = self._observe(rng)
        success = self.task.success_from_distance(self, d)
        reward = float(self._reward_fn(d, d < self.success_threshold_m))
        if self.obs_mode != "goal":  # HER recomputes rewards from goals alone
            # NaN: the compiled shaping needs MuJoCo's contact list, which ``shaping`` reads
            reward += self.task.shaping(self) if shaped is None or shaped != shaped else shaped
        truncated = self._steps >= self.max_episode_steps
        info: dict[str, Any] = {"is_success": success, "distance_m": d}
        if self.privileged_space is not None:
            info["privileged_state"] = self.privileged_state()
        return obs, reward, False, truncated, info

    def render(self) -> np.ndarray | None:
        if self._needs_reset:
            raise gym.error.ResetNeeded("Cannot call env.render() before calling env.reset()")
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
        return self._tool_xpos

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
        (m, world), the targets the safety filter let through (what the servos were sent) and
        the task's extras (``Task.privileged_extra``): no sensor model, no delay
        (``privileged_true_size`` values). Then the last state observation
        (``builder.layout()``): what this env in ``obs_mode="state"`` observes through the same
        sensor models, bit for bit for the same seed and actions, so that a shipped state
        policy can teach a pixel student (``distill``'s ``pick_ppo``). Any ``obs_mode`` has it;
        pixel envs also report it in ``info``."""
        q = self.data.qpos[self._qadr]
        if self.task.uses_gripper:
            q = np.append(q, self.gripper_angle_rad())
        tool = self.data.site_xpos[self._tool_site]
        points = self.task.true_points(self).reshape(-1)
        extra = self.task.privileged_extra(self)
        parts = [q, self._targets, tool, points, self._sent, extra, self._state_obs]
        return np.concatenate(parts).astype(np.float32)

    def _init_fused(self) -> None:
        """What the compiled step needs that a reset does not change (``sim2real.envs.fused``)."""
        spec, n_j = self.spec_arm, self.spec_arm.n_joints
        unknown = [f.name for f in self.builder.fields if f.name not in fused.FIELDS]
        if unknown:
            raise ConfigError(
                f"observation fields {unknown} have no source; known: {[*fused.FIELDS]}"
            )
        if self.task.goal_rule not in fused.GOAL_RULES:
            raise UnknownNameError("goal_rule", self.task.goal_rule, fused.GOAL_RULES)
        self._layout = np.array(
            [(fused.FIELDS[f.name], f.start, f.stop - f.start) for f in self.builder.layout()],
            dtype=np.int64,
        )
        md = self.decoder.max_delta_rad
        self._max_delta = {np.dtype(np.float32): np.float32(md), np.dtype(np.float64): md}
        self._lo_rad, self._hi_rad = spec.lower_rad, spec.upper_rad
        self._home_rad, self._actuator_home_rad = spec.home_rad, spec.actuator_home_rad
        # MuJoCo's arrays are views of its buffers, valid while ``data`` lives: fetched once
        self._qpos, self._ctrl = self.data.qpos, self.data.ctrl
        self._tool_xpos = self.data.site_xpos[self._tool_site]
        g = spec.gripper
        closed, opened, gap = (g.closed_rad, g.open_rad, g.max_gap_m) if g else (0.0, 1.0, 1.0)
        # ``fused.command``'s constants; ``_configure_fused`` writes the episode's servo
        o = 2 * n_j
        self._cmd = np.zeros(o + fused.N_CMD)
        self._cmd[:o] = np.concatenate([self._lo_rad, self._hi_rad])
        # views of its slots, for the safety filter's path (decode, filter, actuate)
        self._decode_grip = self._cmd[o + fused.C_DECODE_GRIP : o + fused.C_SERVO]
        self._servo_prm = self._cmd[o + fused.C_SERVO : o + fused.C_CTRL_GRIP]
        self._ctrl_grip = self._cmd[o + fused.C_CTRL_GRIP : o + fused.N_CMD]
        self._decode_grip[:] = (float(self.decoder.use_gripper and g is not None), closed, opened)
        self._ctrl_grip[:] = (float(self.twin.has_gripper), closed, opened, gap)
        self._no_noise = np.zeros(n_j)
        self._after_step = type(self.task).after_step is not Task.after_step
        grip_reading = self.task.uses_gripper
        obs_qadr = np.append(self._qadr, self.twin.finger_qadr[:1] if grip_reading else [])
        links, signs = spec.links, [j.sign for j in spec.joints[:3]]
        prm = np.zeros(fused.N_PRM + 2 * self._n_readings)
        prm[fused.P_DT] = self.control_dt_s
        prm[fused.P_GRIP_CLOSED : fused.P_GRIP_READ + 1] = (closed, opened, gap, grip_reading)
        prm[fused.P_HOLD_MARGIN] = self.task.hold_margin_rad
        prm[fused.P_HOLD_NEAR] = self.task.grasp_near_m
        prm[fused.P_HELD_AWAY] = self.task.held_away_m
        grip_kind = g.feedback if g is not None and grip_reading else "measured"
        prm[fused.P_HOLD_RULE] = fused.HOLD_RULES[grip_kind]
        prm[fused.P_BLIND_CAP] = self.task.blind_cap_s
        prm[fused.P_SIGN0 : fused.P_SIGN2 + 1] = signs
        prm[fused.P_UPPER : fused.P_TOOL_DOWN + 1] = (
            links.upper_arm_m, links.forearm_m, links.tool_forward_m, links.base_height_m,
            links.tool_down_m,
        )  # fmt: skip
        prm[fused.P_GOAL_RULE] = fused.GOAL_RULES[self.task.goal_rule]
        prm[fused.P_OCCLUDABLE] = self.task.occludable
        # pixels observe without the kernel, and HER's goal env takes no shaping: both call
        # ``Task.shaping`` (or not) as before
        compiled = self.task.shaping_rule != "none" and self.obs_mode == "state"
        if self.task.shaping_rule not in fused.SHAPING_RULES:
            raise UnknownNameError("shaping_rule", self.task.shaping_rule, fused.SHAPING_RULES)
        prm[fused.P_SHAPING] = fused.SHAPING_RULES[self.task.shaping_rule] if compiled else 0
        self._shaping_compiled = compiled
        self._geom_xpos = self.data.geom_xpos  # a view of MuJoCo's buffer, as ``_qpos``
        fused.put_camera(prm, self.sensors)
        self._prm = prm
        self._obs_ints = fused.observe_ints(obs_qadr, self._layout)
        self._rng_binding = fused.RngBinding()  # the generator ``observe`` draws from
        self._sensor_noise = self.sensors.noise_buffer(self.task.n_points + 1)

    def _configure_fused(self) -> None:
        """The episode's servo and sensor parameters into the compiled step's arrays."""
        servo, sensors = self.actuation.servo, self.sensors
        self._servo_prm[:] = (
            servo.max_step_rad,
            servo.deadband_rad,
            servo.quantum_rad,
            servo.per_quantum,
        )
        fused.put_sensing(self._prm, sensors)
        delay, k = sensors.delay_steps, self.task.n_points
        self._obs_ints[: fused.S_RNG_NEXT] = (delay, 0, 0, 0)
        self._obs_ints[fused.S_CARRIED] = 0
        self._obs_mem = fused.observe_memory(k, self._n_readings, delay)
        self._goals = fused.observe_goals(self._obs_mem, k)

    def _observe(self, rng: np.random.Generator) -> tuple[Any, float, float | None]:
        """The observation, the true achieved-to-desired distance (what success and reward
        are judged on) and the task's compiled shaping (None: not compiled here, see
        ``Task.shaping_rule``; NaN: it needs the contact list, ``Task.shaping`` reads it). One
        compiled call senses (``SensorModel``: read, occlude, delay), forms the task's goal,
        fills the layout and shapes; the normals come from the sensor model's buffer and the
        occlusion's uniforms from ``rng`` inside the kernel (``fused.RngBinding``), in the order
        and number the numpy models draw them."""
        task = self.task
        achieved, desired = task.true_goals(self)
        if self.obs_mode == "pixels":
            # sensed as in "state" (the same draws from ``rng``): the proprioception and the
            # privileged state's tail are the state env's observation
            vec, d, _ = self._observe_state(rng, achieved, desired)
            self._state_obs = vec
            if not self.proprio:
                return self._pixels(), d, None
            return {PIXELS_KEY: self._pixels(), PROPRIO_KEY: vec[self._proprio_idx]}, d, None
        vec, d, shaped = self._observe_state(rng, achieved, desired)
        self._state_obs = vec
        if self.obs_mode == "goal":
            goals = self._goals.astype(np.float32)
            obs = {"observation": vec, "achieved_goal": goals[0], "desired_goal": goals[1]}
            return obs, d, None
        return vec, d, shaped if self._shaping_compiled else None

    def _observe_state(
        self, rng: np.random.Generator, achieved: np.ndarray, desired: np.ndarray
    ) -> tuple[np.ndarray, float, float]:
        """The state vector (one compiled call, see ``_observe``), the distance, the shaping."""
        task = self.task
        ints = self._obs_ints
        points = task.true_points(self)
        noise = self._sensor_noise.take(rng)  # ``SensorModel.draw``'s normals
        if rng is not self._rng_binding.rng:  # the kernel draws the occlusion uniforms from it
            self._rng_binding.bind(ints, rng)
        vec = np.empty(self.builder.size, dtype=np.float32)
        d, shaped = fused.observe(
            self._qpos, self._tool_xpos, points, self._prm, ints, noise, self._obs_mem,
            self._targets, self._sent, self._prev_action, task.obs_aux, achieved, desired, vec,
            self._geom_xpos, task.shaping_ids, task.shaping_prm,
        )  # fmt: skip
        return vec, d, shaped

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
        return self._reward_fn(d, d < self.success_threshold_m).astype(np.float32)
