"""``ArmEnv``: a Gymnasium env over the hardware layer, so a learner can train on the mock or the
real arm with the same observation, action and safety chain the deploy loop runs.

Learning on the arm is the deploy loop with a learner beside it. The env is built from the same
parts as ``sim2real deploy``: a backend from ``runner.BACKENDS`` (the arm, its perception, its
world), the policy's ``PolicyIO`` (the training env's ``ObservationBuilder`` and
``ActionDecoder``, the task's ``DeployContract``), and the deploy loop's ``ControlSession``,
whose public steps (episode start, sense, observe, act, pace, safe stops) it drives instead of
copying them.

One ``step`` is one control period: ``act`` (decode the action against the last targets, send it
through ``Arm.command``: the safety filter runs there, once), ``pace`` (sleep to the next period;
a late period is counted and logged, never an error), ``sense`` (read the joints, perceive, judge
the period with the contract) and ``observe`` (the next observation). The reward is the training env's own function
(``envs.base.REWARDS``) on the perceived goal error, the observation's ``goal_delta``; its
success bonus uses the task's threshold, as ``Arm3Env.step`` does. A task that trains with a
dense shaping term gets it from the contract, on percepts (pick: approach, grasp from the
gripper's readings, lift from the cube estimate).

Episode starts follow the contract: sim and mock place the objects themselves; on a real arm
the arm homes and a person places them (with ``HumanKeys``, after the reset key), the reach
target is virtual (drawn from the contract's placement and judged against the camera estimate
of the tool), and pick waits until the cube is seen and still. ``close()`` parks the arm, puts
torque off and releases every process, thread and port the backend opened.

The learner must keep ``step`` coming at the control rate: gradient updates belong off this
thread (the arm's watchdog e-stops an arm left without commands), and the stepping thread
belongs at the deploy loop's priority (``deploy.realtime.control_thread_priority``, as
``run_policy`` runs the loop): at normal priority the mock arm's real-time process and the rest
of the machine preempt it (bench/arm_env_timing.py; docs/studies/learning-on-the-arm.md).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import math
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from hardware.arm import ArmBase, ArmState
from hardware.errors import SafetyError
from hardware.spec import ArmSpec
from sim2real.deploy.perception import Perception
from sim2real.deploy.policy_io import PolicyIO
from sim2real.deploy.runner import BACKENDS, DeployOptions
from sim2real.deploy.session import ControlSession, DeployStopError, LoopConfig, Sensed
from sim2real.deploy.worlds import World
from sim2real.envs.contract import (
    DeployContract,
    MissingEstimateError,
    ObjectEstimate,
    Percept,
    View,
)
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.finetune.keys import HumanKeys
from sim2real.finetune.results import ArmEndState

log = logging.getLogger(__name__)

ESTOP_KEY_STOP = "stopped by the e-stop key; the arm is held, torque off"

# Tasks whose object can be virtual on a real arm: the object name the contract's placement
# draws. Nothing needs to stand on the table: success is judged from the tool estimate alone.
VIRTUAL_OBJECTS: dict[str, str] = {"reach": "target"}


@dataclass(frozen=True)
class ArmEnvConfig:
    """How the env runs the arm (the policy's own settings come from its ``PolicyIO``)."""

    rate_hz: float = 20.0
    episode_steps: int | None = None  # None: the policy's training episode length
    reward: str | None = None  # a name in envs.base.REWARDS; None: the task's default
    # The training env adds the task's dense shaping (pick: approach, grasp, lift) to the goal
    # term. On the arm it comes from percepts (``DeployContract.shaping``: pick's from the tool
    # and cube estimates and the gripper's readings); a task whose shaping only MuJoCo state
    # can give is refused unless this is off (the goal term alone).
    shaping: bool = True
    start_timeout_s: float = 10.0  # how long an episode waits for its objects to be seen, still
    blind_timeout_s: float = 2.0  # an estimate missing this long mid-episode ends the run
    overrun_warn_fraction: float = 0.2  # a period this much longer than nominal is "late"
    # None: virtual on a world that cannot place objects (a real arm) for tasks in
    # VIRTUAL_OBJECTS; True forces it (tests on the mock), False never.
    virtual_target: bool | None = None
    # None: wait for the human's reset key on a real arm when keys are given.
    confirm_reset: bool | None = None

    def __post_init__(self) -> None:
        from sim2real.envs.base import REWARDS

        self.loop_config()  # validates the rate, episode length and start timeout
        if self.reward is not None and self.reward not in REWARDS:
            raise UnknownNameError("reward", self.reward, REWARDS)
        if not self.blind_timeout_s > 0:
            raise ConfigError(f"blind_timeout_s {self.blind_timeout_s} must be > 0")

    def loop_config(self) -> LoopConfig:
        return LoopConfig(
            rate_hz=self.rate_hz,
            episodes=1,
            episode_steps=self.episode_steps,
            start_timeout_s=self.start_timeout_s,
            overrun_warn_fraction=self.overrun_warn_fraction,
        )


class _VirtualObject:
    """World and perception wrapper for a virtual object: the contract's placement of ``name``
    is kept, not placed, and reported as a perfect estimate (and as the truth in a world that
    judges on the truth)."""

    def __init__(self, world: World, perception: Perception, name: str) -> None:
        self.inner_world, self.inner_perception, self.name = world, perception, name
        self.places_objects = world.places_objects
        self.position_m: np.ndarray | None = None

    # World
    def new_episode(self, placement: dict[str, np.ndarray]) -> None:
        self.position_m = np.asarray(placement[self.name], dtype=float)[:3].copy()
        self.inner_world.new_episode({k: v for k, v in placement.items() if k != self.name})

    def clear(self) -> None:
        self.inner_world.clear()

    def view(self, actuators_rad: np.ndarray, commanded_rad: np.ndarray | None) -> View | None:
        view = self.inner_world.view(actuators_rad, commanded_rad)
        if view is None or self.position_m is None:
            return view
        return dataclasses.replace(view, objects={**view.objects, self.name: self.position_m})

    def close(self) -> None:
        self.inner_world.close()

    # Perception
    def reset(self) -> None:
        self.inner_perception.reset()

    def perceive(self, state: ArmState, command_s: float) -> Percept:
        percept = self.inner_perception.perceive(state, command_s)
        if self.position_m is None:
            return percept
        estimate = ObjectEstimate(self.position_m.copy(), 0.0)
        return Percept(
            percept.tool_m, {**percept.objects, self.name: estimate}, percept.tool_blind_s
        )


def training_reward(env_id: str, env_kwargs: Mapping[str, Any]) -> str | None:
    """The reward name a policy's training env used (its id's registered kwargs, then the
    run's own), or None for the task's default."""
    import sim2real.envs  # noqa: F401 - registers the ids

    reward = {**gym.spec(env_id).kwargs, **dict(env_kwargs)}.get("reward")
    return None if reward is None else str(reward)


class ArmEnv(gym.Env[np.ndarray, np.ndarray]):
    """Any ``Arm`` backend (``sim``, ``mock``, ``serial``) as a Gymnasium env for one task."""

    metadata = {"render_modes": []}  # noqa: RUF012 - gymnasium's convention

    def __init__(
        self,
        io: PolicyIO,
        spec: ArmSpec,
        opts: DeployOptions,
        config: ArmEnvConfig | None = None,
        human: HumanKeys | None = None,
    ) -> None:
        from sim2real.envs.base import REWARDS, TASKS, Task

        self.io, self.arm_spec, self.opts = io, spec, opts
        self.config = config = config or ArmEnvConfig()
        task = TASKS[io.task]
        percept_shaping = io.contract.shaping is not DeployContract.shaping
        if config.shaping and task.shaping is not Task.shaping and not percept_shaping:
            raise ConfigError(
                f"task {io.task!r} trains with a dense shaping term that reads MuJoCo state "
                f"({task.__name__}.shaping), not percepts: pass shaping=False to learn on the "
                "goal term alone"
            )
        self.shaped = config.shaping and percept_shaping
        names = {f.name for f in io.builder.fields}
        if "goal_delta" not in names:
            raise ConfigError(
                f"ArmEnv takes flat state policies; the {io.task!r} layout has no goal_delta "
                "(a goal-conditioned policy)"
            )
        self.reward_name = config.reward or task.default_reward
        self._reward_fn = REWARDS[self.reward_name]
        self._success_m = task.success_threshold_m
        self.human = human
        self.period_s = 1.0 / config.rate_hz
        self.episode_steps = config.episode_steps or io.episode_steps

        self._stack = contextlib.ExitStack()
        self._closed = False
        try:
            arm, perception, world = BACKENDS[opts.backend](spec, io, opts, self._stack)
            virtual = config.virtual_target
            if virtual is None:
                virtual = not world.places_objects and io.task in VIRTUAL_OBJECTS
            self.virtual: _VirtualObject | None = None
            if virtual:
                if io.task not in VIRTUAL_OBJECTS:
                    raise ConfigError(
                        f"task {io.task!r} has no virtual object (tasks with one: "
                        f"{sorted(VIRTUAL_OBJECTS)}): a person places its objects"
                    )
                self.virtual = _VirtualObject(world, perception, VIRTUAL_OBJECTS[io.task])
                world, perception = self.virtual, self.virtual
            self.confirm_reset = (
                config.confirm_reset
                if config.confirm_reset is not None
                else human is not None and not world.places_objects
            )
            if self.confirm_reset and human is None:
                raise ConfigError("confirm_reset needs HumanKeys (the reset key)")
        except BaseException:
            self._stack.close()
            raise
        self.arm: ArmBase = arm
        self.perception: Perception = perception
        self.world: World = world
        # no trajectory log (finetune records its own transitions), no pipelined commands
        self.session = ControlSession(arm, perception, world, io, config.loop_config())
        if human is not None and human.on_estop is None:
            # the key stops the arm at once, from the key thread, and nothing but a person's
            # enable() moves it again (not the next reset's homing)
            human.on_estop = functools.partial(arm.estop, operator=True)
            self._stack.callback(setattr, human, "on_estop", None)  # not past close()

        # Real time and real sensors: the same seed places the same objects, but no two runs
        # observe the same thing. The spec says so (check_env then skips its replay checks) and
        # makes a twin on the same backend (check_env's close check builds and closes one).
        self.spec = gym.envs.registration.EnvSpec(
            "Sim2Real/ArmEnv-v0",
            entry_point=f"{__name__}:ArmEnv",
            nondeterministic=True,
            kwargs={"io": io, "spec": spec, "opts": opts, "config": config},
        )
        self.action_space = gym.spaces.Box(-1.0, 1.0, (io.decoder.n_actions,), dtype=np.float32)
        self.observation_space = gym.spaces.Box(
            -np.inf, np.inf, (io.builder.size,), dtype=np.float32
        )
        self._goal_delta = next(slice(f.start, f.stop) for f in io.builder.layout()
                                if f.name == "goal_delta")  # fmt: skip
        self._contract: DeployContract | None = None  # the episode in flight
        self.episodes = 0
        self.blind_periods = 0
        self.estops: list[str] = []  # e-stops (watchdog, faults) that a reset recovered from
        self.end_state: ArmEndState | None = None  # where close() left the arm
        self._idle_stop = threading.Event()
        self._idle: threading.Thread | None = None

    @classmethod
    def for_policy(
        cls,
        policy_ref: str | Path,
        spec: ArmSpec,
        opts: DeployOptions,
        config: ArmEnvConfig | None = None,
        human: HumanKeys | None = None,
    ) -> ArmEnv:
        """The env a policy (a run dir, an exported file or a shipped name) was trained for,
        on this arm: checked against the arm spec and the policy's control rate as ``deploy``
        checks them, with the reward its training env used unless ``config`` names one."""
        from sim2real.deploy.policy_io import policy_io
        from sim2real.export.policy import load_policy
        from sim2real.policies import resolve_policy

        meta = load_policy(resolve_policy(policy_ref)).meta
        meta.check_spec(spec)
        io = policy_io(spec, meta)
        config = config or ArmEnvConfig(rate_hz=meta.control_hz)
        if abs(meta.control_hz - config.rate_hz) > 1e-9:
            raise ConfigError(
                f"policy {meta.source!r} was trained at {meta.control_hz:g} Hz; run its env at "
                f"that rate, not {config.rate_hz:g} Hz"
            )
        if config.reward is None:
            config = dataclasses.replace(
                config, reward=training_reward(meta.env_id, meta.env_kwargs)
            )
        return cls(io, spec, opts, config, human)

    # ---- gymnasium API ---------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._require_open()
        self._stop_idle_hold()
        recovered = self.arm.estop_reason
        try:
            self._check_estop_key()
            if recovered is not None:  # a watchdog or fault e-stop since the last episode
                self.estops.append(recovered)
                log.warning("the arm was e-stopped (%s): homing it for the next episode", recovered)
            session = self.session
            contract = session.new_contract()
            self._contract = None
            session.home()  # up, then open: a held cube drops
            session.clear()
            if self.confirm_reset:
                assert self.human is not None
                log.warning("place the objects, then press r (or Enter)")
                if not self.human.wait_for_reset(session.hold, self.period_s):
                    self._check_estop_key()
            percept = session.place(contract, self.episodes, self.np_random)
            session.begin(contract, percept, self.episodes)
            self._contract = contract
            obs, _ = self._observe(session.sense(view=False))
        except BaseException as exc:
            self._fail()
            self._raise_if_estop_key(exc)
            raise
        # the learner may take a while before its first step (check_env, a rollout buffer):
        # hold meanwhile, or the host watchdog (2 s) stops the arm under it
        self._start_idle_hold()
        info: dict[str, Any] = {"episode": self.episodes, "task": self.io.task}
        if recovered is not None:
            info["recovered_estop"] = recovered
        if self.virtual is not None and self.virtual.position_m is not None:
            info["virtual_target_m"] = self.virtual.position_m.copy()
        return obs, info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._contract is None:
            raise gym.error.ResetNeeded("call reset() before step() (and after an episode ends)")
        contract = self._contract
        a = np.asarray(action, dtype=float).reshape(-1)
        if a.shape != self.action_space.shape:
            raise ConfigError(f"action shape {a.shape} is not {self.action_space.shape}")
        session = self.session
        self._stop_idle_hold()
        try:
            self._wait_if_paused()
            sent = session.act(a)  # the safety filter, once, inside Arm.command
            session.pace()
            # the world now, truth or estimates: what this step's command did (as the env
            # judges a step after its physics)
            sensed = session.sense()
            reason, view = session.reason, sensed.view
            obs, d_m = self._observe(sensed)
        except BaseException as exc:
            self._fail()
            self._raise_if_estop_key(exc)
            raise
        reward = float(self._reward_fn(d_m, d_m < self._success_m))
        shaping = contract.shaping() if self.shaped else None
        if shaping is not None:
            reward += shaping
        truncated = session.step >= self.episode_steps or reason is not None
        out = contract.outcome()
        info: dict[str, Any] = {
            "is_success": bool(out.success),
            "distance_m": float(out.distance_m),
            "perceived_distance_m": d_m,
            "judged_on": "none" if view is None else "truth" if view.truth else "estimate",
            "period_s": self.periods_s[-1],
            "sent_rad": sent.copy(),
            # what the deploy log records per period (finetune writes it)
            "targets_rad": session.targets_rad.copy(),
            "joints_rad": sensed.state.positions_rad.copy(),
            "ee_est_m": sensed.percept.tool_m,
            "goal_est_m": sensed.percept.position(self.io.contract.objects[0]),
            "true_tool_m": view.tool_m if view is not None and view.truth else None,
        }
        if truncated:
            self._end_episode(out.figures, reason, info)
        return obs, reward, False, truncated, info

    def close(self) -> None:
        """Park the arm (if it was ever enabled and still is), torque off, release everything.
        Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._stop_idle_hold()
        try:
            if self.arm.is_connected and self.arm.is_enabled:
                self.session.park()
            self.end_state = self._end_state()
        finally:
            self._contract = None
            self.session.close()  # the placement checker, if the session built one
            self._stack.close()

    # ---- periods ---------------------------------------------------------------------------
    @property
    def periods_s(self) -> list[float]:
        """Every period's length so far, start to start (the session's clock)."""
        return self.session.clock.periods_s

    @property
    def overruns(self) -> int:
        return self.session.clock.overruns

    def _observe(self, sensed: Sensed) -> tuple[np.ndarray, float]:
        """The observation and the perceived goal error at the start of a period. While an
        estimate is missing the arm holds (one command a period, as the deploy loop does) and
        the period is not a step; missing for ``blind_timeout_s`` stops the run."""
        blind_since: float | None = None
        while True:
            try:
                obs = self.session.observe(sensed)
            except MissingEstimateError as exc:
                now = time.monotonic()
                blind_since = now if blind_since is None else blind_since
                if now - blind_since > self.config.blind_timeout_s:
                    raise DeployStopError(
                        f"the {exc.args[0] if exc.args else 'estimate'} estimate has been "
                        f"missing for {self.config.blind_timeout_s:g} s"
                    ) from None
                self.blind_periods += 1
                self.session.hold()
                self.session.pace()
                sensed = self.session.sense(view=False)
                continue
            flat = np.asarray(obs, dtype=np.float32).copy()
            return flat, float(np.linalg.norm(flat[self._goal_delta]))

    # ---- episodes, humans, failures ----------------------------------------------------------
    def _end_episode(
        self, figures: dict[str, Any], reason: str | None, info: dict[str, Any]
    ) -> None:
        self.session.hold()
        self._start_idle_hold()  # the learner may take a while before the next reset
        info["figures"] = dict(figures)
        if reason is not None:
            info["stop_reason"] = reason
        mark = self.human.take_mark() if self.human is not None else None
        if mark is not None:  # a person saw what the cameras could not judge
            info["judged_success"] = info["is_success"]
            info["is_success"] = mark
            info["judged_on"] = "human"
        log.info(
            "episode %d: success=%s (%s)", self.episodes, info["is_success"], info["judged_on"]
        )
        self.episodes += 1
        self._contract = None

    def _start_idle_hold(self) -> None:
        """Between episodes, and from a reset to the first step, nobody steps: hold the arm
        once a period on a thread of its own, so the watchdogs stay fed while the learner logs,
        saves or evaluates. Stopped (joined) before anything else touches the arm."""
        self._idle_stop.clear()
        self._idle = threading.Thread(target=self._idle_hold, name="armenv-idle", daemon=True)
        self._idle.start()

    def _idle_hold(self) -> None:
        while not self._idle_stop.wait(self.period_s):
            try:
                self.session.hold()
            except Exception as exc:  # the watchdog or the port: the next reset sees it
                log.warning("holding between episodes failed: %s", exc)
                return

    def _stop_idle_hold(self) -> None:
        if self._idle is not None:
            self._idle_stop.set()
            self._idle.join()
            self._idle = None

    def _wait_if_paused(self) -> None:
        self._check_estop_key()
        if self.human is None or not self.human.paused:
            return
        log.warning("paused: the arm holds (press space or p to resume)")
        if not self.human.wait_while_paused(self.session.hold, self.period_s):
            self._check_estop_key()
        self.session.restart_period()  # a pause is not a late period

    def _raise_if_estop_key(self, exc: BaseException) -> None:
        """A command the arm refused because the e-stop key latched it (mid-episode, or while
        homing for the next one) is the key's clean stop, not an error."""
        if isinstance(exc, SafetyError) and self.human is not None and self.human.estopped:
            raise DeployStopError(ESTOP_KEY_STOP) from None

    def _check_estop_key(self) -> None:
        if self.human is not None and self.human.estopped:
            raise DeployStopError(ESTOP_KEY_STOP)

    def _fail(self) -> None:
        """Any error or interrupt mid-episode: hold, park if the arm still answers, torque off;
        the episode in flight is over."""
        self._contract = None
        self._stop_idle_hold()
        if self.human is not None and self.human.estopped:
            with contextlib.suppress(Exception):
                self.arm.disable()  # the e-stop held the arm and put torque off: do not move
            return
        self.session.safe_stop()

    def _require_open(self) -> None:
        if self._closed:
            raise ConfigError("ArmEnv is closed: make a new one")

    def _end_state(self) -> ArmEndState:
        """Where the arm ended: the host's torque flag, and the joints read back before the port
        closes with their distance from the park pose (a parked arm sags by its droop; after an
        e-stop the arm held where it was, then went torque off)."""
        torque_on = bool(self.arm.is_enabled)
        if not self.arm.is_connected:
            return ArmEndState(torque_on, read_error="not connected")
        spec = self.arm.spec
        try:
            q = np.asarray(self.arm.read_state().positions_rad[: spec.n_joints], float)
        except Exception as exc:  # the port is gone: torque off was the firmware's to do
            why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            return ArmEndState(torque_on, read_error=why)
        return ArmEndState(
            torque_on,
            joints_rad=tuple(round(float(v), 4) for v in q),
            park_error_rad=round(float(np.max(np.abs(q - spec.park_rad))), 4),
        )

    @property
    def safety_stats(self) -> dict[str, int]:
        """The safety filter's counters, and the mock world's arm-table contacts."""
        return {**vars(self.arm.safety.stats), **self.session.world_contacts()}

    def timing(self) -> dict[str, float]:
        """Loop timing so far: rate, p99 period jitter against nominal, late periods."""
        periods = np.asarray(self.periods_s)
        if not len(periods):
            return {"loop_hz": math.nan, "p99_jitter_ms": math.nan, "overruns": 0.0}
        jitter = np.abs(periods - self.period_s)
        return {
            "loop_hz": float(1.0 / periods.mean()),
            "p99_jitter_ms": float(np.percentile(jitter, 99) * 1e3),
            "overruns": float(self.overruns),
        }
