"""One control session: the steps of an episode and of one control period, on any arm, any task.

A driver runs the steps in order; the steps hold the timing, the safety filter and the episode's
state, so every driver runs them the same way (LeRobot's ``get_observation``/``send_action``
with the loop in the script; SB3's ``learn`` as a thin driver over its steps):

* an episode: ``begin_episode`` (``home`` → ``clear`` → ``place``: the objects placed, seen and
  still → ``begin``), then periods, then ``judge_last`` and ``end_episode``;
  ``safe_stop`` and ``park`` when it ends badly or well;
* a period: ``sense`` (read the arm, perceive, judge on this view what the last command did),
  ``observe`` (the policy's observation), ``act`` (decode → ``Arm.command``, where the safety
  filter runs exactly once → log), ``pace`` (sleep to the next period; overruns counted).

What differs between backends and tasks lives behind small interfaces: the ``Arm``, a
``Perception``, a ``World`` (places the objects and, where it can, tells the truth) and the
task's ``DeployContract``. The observation is built by the training env's ``ObservationBuilder``
and the action decoded by its ``ActionDecoder``. A command is judged as the env judges a step,
after it has acted: on the view at the start of the next period (the last one a period later).
``deploy.loop.DeployLoop`` and ``finetune.arm_env.ArmEnv`` drive it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hardware.arm import ArmBase, ArmState
from hardware.errors import HardwareError
from sim2real.deploy.clock import PeriodClock, log, sleep_until
from sim2real.deploy.perception import Perception
from sim2real.deploy.policy_io import PolicyIO
from sim2real.envs.contract import DeployContract, Outcome, Percept, View
from sim2real.errors import ConfigError, Sim2RealError
from sim2real.observation import command_readings

if TYPE_CHECKING:  # worlds import MuJoCo; the deploy profile runs without it
    from sim2real.deploy.worlds import World

SECTIONS = ("read", "perceive", "infer", "command")


class DeployStopError(Sim2RealError):
    """The run stopped for a reason the user must act on (the arm is parked, the log kept)."""


@dataclass(frozen=True)
class LoopConfig:
    rate_hz: float = 20.0
    episodes: int = 10
    episode_steps: int | None = None  # None: the policy's training episode length
    seed: int = 1_000_000  # held out: training seeds are small integers
    dry_run: bool = False
    overrun_warn_fraction: float = 0.2  # warn when a period runs 20 % long
    start_timeout_s: float = 10.0  # how long an episode waits for its objects to be seen, still
    # Mid-episode, the tool (its wrist plate) or an object unseen by the cameras for longer
    # than this stops the run: held, then parked. Above the blind spells a run has (the
    # gripper hides a carried cube: ~0.3 s on the mock, pick's reading saturates at 2 s),
    # below what a policy acting on stale estimates should be let do. None: no limit.
    blind_limit_s: float | None = 3.0
    # Episode i's objects (``DeployContract.placement``'s format), replayed instead of drawn:
    # env and deploy runs, or two backends, compare on the same placements (``Task.placement``).
    placements: tuple[Mapping[str, Any], ...] = field(default=(), compare=False)

    def __post_init__(self) -> None:
        if not 0.5 <= self.rate_hz <= 500:
            raise ConfigError(f"rate_hz {self.rate_hz} not in [0.5, 500]")
        if self.episodes < 1 or (self.episode_steps is not None and self.episode_steps < 1):
            raise ConfigError(
                f"episodes ({self.episodes}) and episode_steps ({self.episode_steps}) must be >= 1"
            )
        if not self.start_timeout_s > 0:
            raise ConfigError(f"start_timeout_s {self.start_timeout_s} must be > 0")
        if self.blind_limit_s is not None and not (
            math.isfinite(self.blind_limit_s) and self.blind_limit_s > 0
        ):
            raise ConfigError(f"blind_limit_s {self.blind_limit_s} must be > 0 (or None: no limit)")
        if self.placements and len(self.placements) < self.episodes:
            raise ConfigError(
                f"placements: {len(self.placements)} given for {self.episodes} episodes"
            )


LOG_KEYS = (
    "t_s",
    "episode",
    "step",
    "obs",
    "action",
    "targets_rad",
    "sent_rad",
    "joints_rad",
    "ee_est_m",
    "ee_seen",
    "goal_est_m",
    "true_tool_m",
    "period_s",
    "wake_late_s",
    *(f"{s}_s" for s in SECTIONS),
)


@dataclass
class LoopLog:
    """Everything per period, for replay, sysid and datasets (saved as npz). ``objects`` holds
    each tracked object's estimate (``<name>_est_m``) and blind time (``<name>_blind_s``). The
    truth (``true_tool_m``, ``<name>_true_m``, ``grasped``) is the world at the period's read,
    beside its estimates: the view that judged the previous period's command."""

    rows: dict[str, list[Any]] = field(default_factory=lambda: {k: [] for k in LOG_KEYS})

    def add(self, **values: Any) -> None:
        for key, value in values.items():
            self.rows.setdefault(key, []).append(value)

    def save(self, path: Path) -> Path:
        import io

        from hardware.atomic import atomic_write_bytes

        arrays = {}
        for key, values in self.rows.items():
            if values:
                width = next((np.size(v) for v in values if v is not None), 1)
                arrays[key] = np.asarray(
                    [np.full(width, np.nan) if v is None else v for v in values], dtype=float
                )
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        atomic_write_bytes(path, buf.getvalue())
        return path


@dataclass
class EpisodeRecord:
    success: bool
    distance_m: float
    figures: dict[str, Any]
    reason: str | None


@dataclass(frozen=True)
class Sensed:
    """A period's start: the arm's reading, the percept at it, and the view that judged the
    last command (None: nothing viewed, or nothing to judge it on)."""

    state: ArmState
    percept: Percept
    view: View | None
    t_s: float  # perf_counter at the read: the period's time in the log
    read_s: float
    perceive_s: float  # perception and the view
    period_s: float  # the period before this one (NaN: the episode's first)
    wake_late_s: float  # its wake-up after the deadline (NaN: it did not sleep)


PUT_DOWN_CLEAR_M = 0.04  # the open gripper rises this far from a set-down object


class ControlSession:
    """One arm with its perception and world, running one policy's ``PolicyIO``."""

    PLACEMENT_TRIES = 3  # a world that places objects may put one where the cameras miss it
    # objects a world placed and the cameras have not seen in this long: the arm at home may
    # hide one, so it parks (the mock's cameras see a visible placement in about 0.5 s; a loaded
    # machine that takes longer only pays a needless park and home, ~0.6 s, never a failure)
    LOOK_FROM_PARK_S = 1.5
    MAX_PLACEMENT_DRAWS = 50

    def __init__(
        self,
        arm: ArmBase,
        perception: Perception,
        world: World,
        io: PolicyIO,
        config: LoopConfig,
        log: LoopLog | None = None,
        obs_keys: tuple[str, ...] | None = None,
        pipelined: bool = False,
    ) -> None:
        self.arm, self.perception, self.world = arm, perception, world
        self.io, self.builder, self.decoder = io, io.builder, io.decoder
        self.config = config
        self.steps = config.episode_steps or io.episode_steps
        self.log = log  # None: no rows kept (a learner records its own transitions)
        self.obs_keys = obs_keys  # dict-observation policies (HER): their key order
        self.pipelined = pipelined  # SerialArm.set_pipelined in an episode's periods
        # a lockstep world waits for the loop (its period; None: the arm moves with the wall
        # clock): nothing here sleeps for it
        self.lockstep_s = arm.lockstep_period_s
        self._lockstep_wait_s = 0.0  # the lockstep world's time spent waiting for objects
        self.clock = PeriodClock(
            config.rate_hz, config.overrun_warn_fraction, sleeps=self.lockstep_s is None
        )
        self.sections_s: dict[str, list[float]] = {s: [] for s in SECTIONS}
        self._n_obs_joints = self.builder.fields[0].size
        self._has_goal_delta = "target_goal_delta" in {f.name for f in self.builder.fields}
        self._sight: Any = None  # placement.RigSight, built on the first placement it checks
        # the episode in flight
        self.contract: DeployContract | None = None
        self.episode = 0
        self.step = 0  # commands sent this episode
        self.targets_rad = np.zeros(self.decoder.spec.n_actuators)
        self.prev_action = np.zeros(self.decoder.n_actions)
        self.sent_rad: np.ndarray | None = None  # the last command, judged one period later
        self.reason: str | None = None  # why the episode stopped early
        self.blind_periods = 0  # this episode's periods without a usable estimate
        self._judged = True  # the last command has been judged (or there is none)
        self._t_sent = 0.0
        self._missing_since: dict[str, float] = {}  # objects whose track was lost mid-episode
        self._begun_s = 0.0  # when the episode's first period started (monotonic)

    # ---- an episode ---------------------------------------------------------------------------
    def new_contract(self) -> DeployContract:
        return self.io.new_contract(self.decoder.spec, self.config.rate_hz)

    def begin_episode(self, episode: int, rng: np.random.Generator) -> None:
        """Home (up, then open: a held cube drops), clear the table, place the objects and wait
        until they are seen and still, then begin the contract."""
        contract = self.new_contract()
        self.home()
        self.clear()
        self.begin(contract, self.place(contract, episode, rng), episode)

    def home(self) -> None:
        """Home in two moves: the joints first, the gripper as it is (a cube pressed against the
        table would wedge the fingers), then the gripper opens up high and a held cube drops.
        A dry run moves nothing."""
        if self.config.dry_run:
            return
        n = self.decoder.spec.n_joints
        try:
            self.put_down()
            if self.arm.is_enabled and self.decoder.spec.n_actuators > n:
                target = self.decoder.spec.actuator_home_rad.copy()
                target[n:] = self.arm.read_state().positions_rad[n:]
                self.arm.move_to(target)
            self.arm.home()
        except HardwareError as exc:
            if not self.world.places_objects:
                raise  # a real arm: a person must look at what blocks it
            # simulated contacts can wedge a turned cube between the fingers: take it away
            log.warning("home failed (%s): clearing the table and homing again", exc)
            self.world.clear()
            self.arm.home()

    def put_down(self) -> None:
        """What the arm holds goes back on the table before it homes or parks (the contract
        says where; pick: a held cube, set down where the tool is), then the gripper opens
        there. Nothing held, or an arm without its torque on: nothing to do."""
        last = self.arm.last_sent_rad
        if self.contract is None or last is None or not self.arm.is_enabled:
            return
        target = self.contract.put_down(self.arm.read_state().positions_rad, last)
        if target is None:
            return
        log.info("setting the held object down before the arm moves on")
        joints = np.arange(self.decoder.spec.n_actuators) < self.decoder.spec.n_joints
        try:  # the gripper stays commanded shut and stops at the object: judge the joints
            self.arm.move_to(target, judged=joints)
        except HardwareError as exc:  # the table stopped it short: let go from there
            log.warning("setting the held object down stopped short (%s); opening there", exc)
            target = self.arm.read_state().positions_rad.copy()
            target[self.decoder.spec.n_joints :] = last[self.decoder.spec.n_joints :]
        spec, n = self.decoder.spec, self.decoder.spec.n_joints
        opened = target.copy()
        opened[n:] = spec.actuator_home_rad[n:]
        self.arm.move_to(opened)
        # up and clear of it, the gripper open, before a park closes the fingers again
        above = spec.forward_kinematics(opened[:n]) + (0.0, 0.0, PUT_DOWN_CLEAR_M)
        q = spec.inverse_kinematics(above)
        if q is not None:
            opened[:n] = q
            self.arm.move_to(opened)

    def clear(self) -> None:
        """Sim and mock: the last episode's objects off the table."""
        self.world.clear()

    def place(self, contract: DeployContract, episode: int, rng: np.random.Generator) -> Percept:
        """Place the episode's objects (sim, mock) and wait until they are seen and still. A
        world that places them tries a new placement when the cameras cannot see one (behind
        the arm's base); on a real arm the first timeout stops the run."""
        tries = self.PLACEMENT_TRIES if self.world.places_objects else 1
        replayed = self.config.placements
        for attempt in range(tries):
            if replayed:  # the same objects on every try: pairs stay paired
                placed = {k: np.asarray(v, dtype=float) for k, v in replayed[episode].items()}
                self.world.new_episode(placed)
            else:
                self.world.new_episode(self._placement(contract, rng))
            self.perception.reset()
            try:
                return self._wait_until_ready(contract, episode)
            except DeployStopError as exc:
                if attempt + 1 == tries:
                    raise
                log.warning("%s: placing the objects anew", exc)
                self.world.clear()
                if not self.config.dry_run:
                    self.arm.home()
        raise AssertionError("unreachable")  # pragma: no cover

    def begin(self, contract: DeployContract, percept: Percept, episode: int) -> None:
        """The episode's first period starts: the contract sees its objects, the targets start
        where the arm is, the clock starts."""
        contract.begin(percept)
        self.contract, self.episode = contract, episode
        self.targets_rad = self.arm.read_state().positions_rad.copy()
        self.prev_action = np.zeros(self.decoder.n_actions)
        self.step = self.blind_periods = 0
        self.sent_rad, self.reason, self._judged = None, None, True
        self._missing_since = {}
        self._begun_s = time.monotonic()
        self.clock.start()
        if self.pipelined:
            self.set_pipelined(True)

    def judge_last(self) -> str | None:
        """After an episode's last period: give its command one whole period to act, then judge
        it on a view taken then."""
        if self.lockstep_s is None:  # in lockstep the command acted for a whole period when sent
            sleep_until(self._t_sent + self.clock.period_s)
        if self.sent_rad is None:
            return self.reason
        contract = self._require_contract()
        state = self.arm.read_state()
        percept = self.perception.perceive(state, time.monotonic())
        view = self.view(contract, percept, state.positions_rad, self.sent_rad)
        reason = None if view is None else contract.score(view, self.step - 1)
        if reason is not None:
            log.warning("episode stopped at its last period: %s", reason)
        self.reason = reason or self.reason
        return self.reason

    def end_episode(self) -> EpisodeRecord:
        """The contract's outcome; the arm holds before any slow bookkeeping (video encoding)."""
        if self.pipelined:
            self.set_pipelined(False)
        out = self._require_contract().outcome()
        record = EpisodeRecord(out.success, out.distance_m, out.figures, self.reason)
        self.hold()
        return record

    def outcome(self) -> Outcome:
        """The contract's outcome so far."""
        return self._require_contract().outcome()

    # ---- one period ---------------------------------------------------------------------------
    def sense(self, view: bool = True) -> Sensed:
        """A period starts: read the arm, perceive, and judge what the last command did on the
        world now (truth or estimates), as the env judges a step after its physics. With
        ``view=False``, read and perceive only: a re-read inside a period has nothing to judge."""
        contract = self._require_contract()
        period_s, late_s = self.clock.tick()
        t0 = time.perf_counter()
        state = self.arm.read_state()
        t1 = time.perf_counter()
        now = time.monotonic()
        percept = self.perception.perceive(state, now)
        self.check_blind(contract, percept, now)
        seen: View | None = None
        if view:
            seen = self.view(contract, percept, state.positions_rad, self.sent_rad)
            if not self._judged and seen is not None:
                self.reason = contract.score(seen, self.step - 1) or self.reason
            self._judged = True
        t2 = time.perf_counter()
        return Sensed(state, percept, seen, t0, t1 - t0, t2 - t1, period_s, late_s)

    def check_blind(self, contract: DeployContract, percept: Percept, now_s: float) -> None:
        """Mid-episode, the tool or an object unseen longer than ``blind_limit_s`` (an object
        whose track was lost counts from its loss) raises ``DeployStopError``: the driver's
        safe stop holds, then parks. Counted from the episode's start at most: before it, the
        arm may have parked out of the cameras' way while it looked for the objects."""
        limit = self.config.blind_limit_s
        if limit is None:
            return
        blind = {"tool": percept.tool_blind_s}
        hidden = contract.expected_hidden()
        for name in contract.objects:
            if name in hidden:  # carried in the fingers: the task's estimate stands in
                self._missing_since.pop(name, None)
                continue
            b = percept.blind_s(name)
            if math.isinf(b):
                b = now_s - self._missing_since.setdefault(name, now_s)
            else:
                self._missing_since.pop(name, None)
            blind[name] = min(b, now_s - self._begun_s)
        blind["tool"] = min(blind["tool"], now_s - self._begun_s)
        worst = max(blind, key=lambda k: blind[k])
        if blind[worst] > limit:
            raise DeployStopError(
                f"blind: {worst} unseen by the cameras for {blind[worst]:.1f} s mid-episode "
                f"(limit {limit:.1f} s); held, then parked"
            )

    def observe(self, sensed: Sensed) -> Any:
        """The policy's observation; raises ``MissingEstimateError`` while an estimate is
        missing (a tracker lost its object)."""
        contract = self._require_contract()
        positions_rad, targets = sensed.state.positions_rad, self.targets_rad
        contract.observe_arm(positions_rad, targets)
        readings = contract.readings(sensed.percept, self.step)
        goal = contract.goal_m(sensed.percept, self.step) if self._has_goal_delta else None
        vec = self.builder.build(
            {
                "joint_pos": positions_rad[: self._n_obs_joints],
                "joint_target": targets[: self._n_obs_joints],
                "prev_action": self.prev_action,
                **readings,
                **command_readings(self.decoder.spec, targets, goal),
            }
        )
        if self.obs_keys is None:
            return vec
        desired = readings["goal_pos"]
        achieved = desired - readings["goal_delta"]
        return {
            "observation": vec,
            "achieved_goal": np.asarray(achieved, dtype=np.float32),
            "desired_goal": np.asarray(desired, dtype=np.float32),
        }

    def blind_period(self) -> tuple[np.ndarray, np.ndarray]:
        """A period without a usable estimate: a NaN observation and the action that holds
        still and keeps the watchdogs fed (the gripper action is absolute: kept, or a held cube
        drops). A camera that stops delivering raises instead."""
        self.blind_periods += 1
        obs = np.full(self.builder.size, np.nan, dtype=np.float32)
        action = np.zeros(self.decoder.n_actions)
        n = self.decoder.spec.n_joints
        action[n:] = self.prev_action[n:]
        return obs, action

    def act(self, action: np.ndarray, sensed: Sensed | None = None, obs: Any = None) -> np.ndarray:
        """Decode the action against the last targets and command them: the safety filter runs
        exactly once, inside ``Arm.command`` (a dry run filters and sends nothing). A sensed
        period becomes a log row. Returns what was sent."""
        t3 = time.perf_counter()
        self.targets_rad = self.decoder.decode(action, self.targets_rad)
        if self.config.dry_run:  # read and log, send nothing: the filter still judges it
            last = self.arm.last_sent_rad
            sent = self.arm.safety.filter(
                self.targets_rad, self.targets_rad if last is None else last
            )
        else:
            sent = self.arm.command(self.targets_rad)
        t4 = time.perf_counter()
        self.prev_action = np.clip(action, -1.0, 1.0)
        self.sent_rad, self._t_sent, self._judged = sent, t4, False
        self.step += 1
        if sensed is not None:
            infer_s = t3 - (sensed.t_s + sensed.read_s + sensed.perceive_s)
            timings = (sensed.read_s, sensed.perceive_s, infer_s, t4 - t3)
            for name, dt in zip(SECTIONS, timings, strict=True):
                self.sections_s[name].append(dt)
            if self.log is not None:
                self.log_period(sensed, obs, action)
        return sent

    def pace(self) -> None:
        """Sleep to the next period's start (``PeriodClock``)."""
        self.clock.sleep()

    def log_period(self, sensed: Sensed, obs: Any, action: np.ndarray) -> None:
        """The period just commanded as one log row: what was read, estimated, decided, sent."""
        if self.log is None:
            return
        view, percept = sensed.view, sensed.percept
        truth = view if view is not None and view.truth else None
        objects = self.io.contract.objects
        extra: dict[str, Any] = {}
        for name in objects:
            extra[f"{name}_est_m"] = percept.position(name)
            extra[f"{name}_blind_s"] = percept.blind_s(name)
            extra[f"{name}_true_m"] = truth.objects.get(name) if truth is not None else None
        if truth is not None:
            extra["grasped"] = math.nan if truth.grasped is None else float(truth.grasped)
        ee_seen = getattr(self.perception, "ee_seen", None)
        self.log.add(
            t_s=sensed.t_s,
            episode=self.episode,
            step=self.step - 1,
            obs=obs["observation"] if isinstance(obs, dict) else obs,
            action=action,
            targets_rad=self.targets_rad,
            sent_rad=self.sent_rad,
            joints_rad=sensed.state.positions_rad,
            ee_est_m=percept.tool_m,
            ee_seen=float(bool(ee_seen)) if ee_seen is not None else math.nan,
            goal_est_m=percept.position(objects[0]),
            true_tool_m=truth.tool_m if truth is not None else None,
            period_s=sensed.period_s,
            wake_late_s=sensed.wake_late_s,
            **{f"{n}_s": self.sections_s[n][-1] for n in SECTIONS},
            **extra,
        )

    def restart_period(self) -> None:
        """The current period starts again now (after a pause: not a late period)."""
        self.clock.restart()

    # ---- the world as seen --------------------------------------------------------------------
    def view(
        self,
        contract: DeployContract,
        percept: Percept,
        positions_rad: np.ndarray,
        commanded_rad: np.ndarray | None,
    ) -> View | None:
        """The world as perceived at the start of a period: the truth where the world knows it,
        else the estimates. It judges the previous period's command, which has had one period
        to act (as the env judges a step after its physics); judged right after the command,
        the tool would lag by one period of motion (~3 mm per sample on a moving seam)."""
        view = self.world.view(positions_rad, commanded_rad)
        if view is None:  # a real arm: judge on the estimates
            view = _estimate_view(contract, percept, positions_rad, commanded_rad)
        return view

    def world_contacts(self) -> dict[str, int]:
        """``{"table_contacts": n}`` where the world measures it (the mock arm's MuJoCo: physics
        steps with an arm link on the table), else nothing."""
        count = getattr(self.world, "table_contacts", None)
        n = count() if callable(count) else None
        return {} if n is None else {"table_contacts": int(n)}

    # ---- safe states --------------------------------------------------------------------------
    def hold(self) -> None:
        """Between periods (no policy running) keep every watchdog fed: the arm does not move."""
        if self.arm.is_enabled and not self.config.dry_run:
            self.arm.hold()

    def park(self) -> None:
        """At the end of a run: parked on its rest, torque off until the next run."""
        if self.config.dry_run:
            return
        try:
            self.put_down()
            self.arm.park()
            self.arm.disable()
        except HardwareError as exc:
            log.warning("park failed: %s", exc)
            self.safe_stop()

    def set_pipelined(self, on: bool) -> None:
        """Pipelined commands (``SerialArm.set_pipelined``) in an episode's periods only: a
        period then waits for one serial round trip, its reading, not two."""
        setter = getattr(self.arm, "set_pipelined", None)
        if setter is not None and not self.config.dry_run:
            setter(on)

    def safe_stop(self) -> None:
        """Hold, park if the arm still answers, then torque off. An arm that stopped itself on a
        fault (a stall, a pose it could not reach, a brown-out: ``ArmBase``'s fault stop) is
        already held up and parked slowly with its torque on: it is left so, not dropped; its
        torque goes off when the host lets go of it (close, or the firmware watchdog)."""
        try:
            self.set_pipelined(False)
        except Exception as exc:  # the posted command's reply is lost: stop all the same
            log.warning("the last command's reply: %s", exc)
        fault = self.arm.estop_reason
        if fault is not None and self.arm.is_enabled and self.arm.is_connected:
            log.warning("the arm stopped itself (%s); it is left holding, torque on", fault)
            return
        try:
            if self.arm.is_enabled and not self.config.dry_run:
                self.arm.hold()
                self.arm.park()
        except Exception as exc:  # the port may be gone: still try torque-off below
            log.warning("could not park: %s", exc)
        finally:
            try:
                self.arm.disable()
            except Exception as exc:
                log.warning("torque-off failed: %s", exc)

    def save_log(self, path: Path | None) -> None:
        """The trajectory log, if one is kept and wanted; a failed write is reported, not
        raised (the arm's safe stop comes first)."""
        if path is not None and self.log is not None:
            try:
                self.log.save(path)
            except OSError as exc:
                log.error("could not write the trajectory log %s: %s", path, exc)

    def close(self) -> None:
        """Release what the session opened itself (the placement checker's renderer); the arm,
        perception and world belong to whoever built them."""
        if self._sight is not None:
            self._sight.close()
            self._sight = None

    # ---- episode start ------------------------------------------------------------------------
    def check_placements(self) -> None:
        """Every replayed placement names what the task places, with the contract's shapes:
        checked before the arm moves (a bad placement is a config error, not a stop)."""
        contract = self.new_contract()
        drawn = contract.placement(np.random.default_rng(0))
        want = {k: np.shape(v) for k, v in drawn.items()}
        for i, placement in enumerate(self.config.placements):
            got = {k: np.shape(v) for k, v in placement.items()}
            if got != want:
                raise ConfigError(
                    f"placement {i} {got} does not match what task {contract.task!r} places: {want}"
                )
            for k, v in placement.items():
                if not np.all(np.isfinite(np.asarray(v, dtype=float))):
                    raise ConfigError(f"placement {i} {k!r} is not finite: {v}")

    def _placement(self, contract: DeployContract, rng: np.random.Generator) -> dict[str, Any]:
        """The contract's next placement; for a task placed in view, the first one the rig's
        cameras find from the home pose (``placement.RigSight``: the sim and mock backends both
        build the default rig, so both draw the same sequence)."""
        placement = contract.placement(rng)
        if not (self.world.places_objects and contract.placed_in_view):
            return placement
        if self._sight is None:
            from sim2real.deploy.placement import RigSight

            self._sight = RigSight.for_task(self.decoder.spec, self.io.task, contract.objects)
        why: str | None = None
        for _ in range(self.MAX_PLACEMENT_DRAWS):
            self.hold()  # a render per draw: keep the watchdogs fed
            why = self._sight.unseen(placement)
            if why is None:
                return placement
            log.info("placement %s drawn again: %s", _placement_str(placement), why)
            placement = contract.placement(rng)
        raise DeployStopError(
            f"no placement the cameras see in {self.MAX_PLACEMENT_DRAWS} draws (last: {why})"
        )

    def _wait_until_ready(self, contract: DeployContract, episode: int) -> Percept:
        """Hold the arm (feeding the watchdogs) until the contract's objects are seen and
        still. Half-way through the timeout the arm parks, low and out of the cameras' way (at
        home it may hide an object), and goes home again once they are seen: the trackers
        coast through that. A world that places the objects itself (sim, mock) knows they are
        there, so its arm parks once ``LOOK_FROM_PARK_S`` pass unseen, not after half of a
        timeout sized for a slow machine. A timeout stops the run with the contract's reason."""
        timeout_s = self.config.start_timeout_s
        park_after_s = 0.5 * timeout_s
        if self.world.places_objects:
            park_after_s = min(park_after_s, self.LOOK_FROM_PARK_S)
        # a lockstep world moves one period per hold (and not at all without one): its objects
        # stand still for as many periods as the wall-clock wait would take, without the wait
        lockstep_s = self.lockstep_s
        start = time.monotonic() if lockstep_s is None else self._lockstep_wait_s
        parked = self.config.dry_run
        while True:
            self.hold()
            wall = time.monotonic()
            percept = self.perception.perceive(self.arm.read_state(), wall)
            if lockstep_s is None:
                now = wall
            else:
                self._lockstep_wait_s += lockstep_s
                now = self._lockstep_wait_s
            waiting = contract.ready(percept, now)
            if waiting is None and percept.tool_m is not None:
                if parked and not self.config.dry_run:
                    self.arm.home()
                    percept = self.perception.perceive(self.arm.read_state(), time.monotonic())
                return percept
            if now > start + timeout_s:
                raise DeployStopError(
                    f"episode {episode} never started: {waiting or 'no tool estimate'} after "
                    f"{timeout_s:.0f} s (objects {list(contract.objects)})"
                )
            if not parked and now - start > park_after_s:
                parked = True
                self.arm.park()
            if lockstep_s is None:
                time.sleep(0.02)

    def _require_contract(self) -> DeployContract:
        if self.contract is None:
            raise ConfigError("no episode in flight: begin one first")
        return self.contract


def _estimate_view(
    contract: DeployContract,
    percept: Percept,
    positions_rad: np.ndarray,
    sent: np.ndarray | None,
) -> View | None:
    if percept.tool_m is None:
        return None
    objects = {n: percept.position(n) for n in contract.objects}
    if any(p is None for p in objects.values()):
        return None
    return View(
        tool_m=percept.tool_m,
        objects={k: v for k, v in objects.items() if v is not None},
        actuators_rad=positions_rad,
        truth=False,
        blind_s={n: percept.blind_s(n) for n in contract.objects},
        commanded_rad=sent,
        tool_then_m={n: t for n in contract.objects if (t := percept.tool_then(n)) is not None},
    )


def _placement_str(placement: Mapping[str, Any]) -> str:
    return ", ".join(
        f"{k} {np.round(np.asarray(v, dtype=float), 3).tolist()}" for k, v in placement.items()
    )
