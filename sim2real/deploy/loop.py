"""The fixed-rate deploy loop: read → perceive → observe → infer → command, for any task.

One loop serves every backend and every task. What differs lives behind small interfaces: the
``Arm`` (MuJoCo, the emulator over a pty, a real bus), a ``Perception`` (the truth, or free-running
cameras → detect → triangulate → Kalman), a ``World`` (places the objects and, where it can,
tells the truth) and the task's ``DeployContract`` (its percepts, how an episode starts, its
observation readings, how success is judged). The observation is built by the same
``ObservationBuilder`` and the action decoded by the same ``ActionDecoder`` as in training.

Every command passes the safety filter exactly once, inside ``Arm.command``. The loop never
waits for a camera: it takes the newest frame pair and the trackers predict to the command time.
On Ctrl-C or any error the arm holds, parks and goes torque-off, and the trajectory log is kept.
Success is judged as the env judges it, after the command has acted: period k on the world seen
at the start of period k+1, and the last period on one more view, a period after its command.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hardware.arm import ArmBase
from hardware.errors import HardwareError
from sim2real.deploy.perception import Perception
from sim2real.deploy.policy_io import PolicyIO
from sim2real.deploy.realtime import QuietGC, single_threaded_blas
from sim2real.envs.contract import DeployContract, MissingEstimateError, Percept, View
from sim2real.errors import ConfigError, Sim2RealError
from sim2real.observation import command_readings

if TYPE_CHECKING:  # worlds import MuJoCo; the deploy profile runs without it
    from sim2real.deploy.worlds import World

log = logging.getLogger(__name__)

SECTIONS = ("read", "perceive", "infer", "command")
Policy = Callable[[Any], np.ndarray]


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


def _percentile_ms(values: list[float], q: float) -> float:
    return float(np.percentile(values, q) * 1e3) if values else float("nan")


@dataclass
class EpisodeRecord:
    success: bool
    distance_m: float
    figures: dict[str, Any]
    reason: str | None


@dataclass
class DeployResult:
    task: str
    episodes: list[EpisodeRecord]
    periods_s: list[float]
    sections_s: dict[str, list[float]]
    overruns: int
    blind_periods: int  # periods without a usable estimate (the arm held still)
    stopped_early: str | None
    safety_stats: dict[str, int]
    watchdog_trips: int
    rate_hz: float
    requested_episodes: int
    # per period after a sleep: the wake-up after the deadline (the kernel's wake-up plus the
    # wait for the GIL), the part of the jitter the period's own work does not explain
    wake_late_s: list[float] = field(default_factory=list)

    @property
    def successes(self) -> int:
        return sum(e.success for e in self.episodes)

    def summary(self) -> dict[str, Any]:
        n = max(len(self.episodes), 1)
        periods = np.asarray(self.periods_s)
        nominal = 1.0 / self.rate_hz
        jitter = np.abs(periods - nominal) if len(periods) else np.zeros(0)
        task_figures: dict[str, Any] = {}
        for key in self.episodes[0].figures if self.episodes else ():
            values = [e.figures[key] for e in self.episodes if key in e.figures]
            if all(isinstance(v, bool | np.bool_) for v in values):
                task_figures[f"{key}_rate"] = float(np.mean(values))
            else:
                finite = [float(v) for v in values if math.isfinite(float(v))]
                task_figures[f"mean_{key}"] = float(np.mean(finite)) if finite else math.nan
        reasons = [e.reason for e in self.episodes if e.reason]
        return {
            "task": self.task,
            "episodes": len(self.episodes),
            "success_rate": self.successes / n,
            "mean_final_distance_m": float(np.nanmean([e.distance_m for e in self.episodes]))
            if self.episodes and any(math.isfinite(e.distance_m) for e in self.episodes)
            else math.nan,
            "task_figures": task_figures,
            "episode_stops": reasons,
            "loop_hz": float(1.0 / periods.mean()) if len(periods) else math.nan,
            "period_jitter_ms": {
                "p50": _percentile_ms(list(jitter), 50),
                "p99": _percentile_ms(list(jitter), 99),
                "max": float(jitter.max() * 1e3) if len(jitter) else math.nan,
            },
            "wake_late_ms": {
                "p50": _percentile_ms(self.wake_late_s, 50),
                "p99": _percentile_ms(self.wake_late_s, 99),
                "max": float(max(self.wake_late_s) * 1e3) if self.wake_late_s else math.nan,
            },
            "overruns": self.overruns,
            "blind_periods": self.blind_periods,
            "watchdog_trips": self.watchdog_trips,
            "sections_ms": {
                s: {"p50": _percentile_ms(v, 50), "p99": _percentile_ms(v, 99)}
                for s, v in self.sections_s.items()
            },
            "safety": self.safety_stats,
            "stopped_early": self.stopped_early,
        }


class DeployLoop:
    """Runs ``policy`` on ``arm`` for N episodes of its task at a fixed rate."""

    def __init__(
        self,
        arm: ArmBase,
        perception: Perception,
        world: World,
        policy: Policy,
        io: PolicyIO,
        config: LoopConfig,
        log_path: Path | None = None,
        on_frame: Callable[[], None] | None = None,
        obs_keys: tuple[str, ...] | None = None,
        on_episode: Callable[[int, bool, dict[str, list[Any]]], None] | None = None,
    ) -> None:
        self.arm, self.perception, self.world = arm, perception, world
        self.policy, self.io = policy, io
        self.builder, self.decoder = io.builder, io.decoder
        self.config = config
        self.steps = config.episode_steps or io.episode_steps
        self.log_path = log_path
        self.log = LoopLog()
        self.on_frame = on_frame
        self.on_episode = on_episode  # (episode, success, the log's rows): dataset recording
        self.obs_keys = obs_keys  # dict-observation policies (HER): their key order
        self._n_obs_joints = self.builder.fields[0].size
        self._has_goal_delta = "target_goal_delta" in {f.name for f in self.builder.fields}
        self._watchdog_trips = 0
        self._sight: Any = None  # placement.RigSight, built on the first placement it checks

    # ---- one period ---------------------------------------------------------------------
    def _observation(
        self,
        contract: DeployContract,
        percept: Percept,
        positions_rad: np.ndarray,
        targets: np.ndarray,
        prev_action: np.ndarray,
        step: int,
    ) -> Any:
        contract.observe_arm(positions_rad, targets)
        readings = contract.readings(percept, step)
        goal = contract.goal_m(percept, step) if self._has_goal_delta else None
        vec = self.builder.build(
            {
                "joint_pos": positions_rad[: self._n_obs_joints],
                "joint_target": targets[: self._n_obs_joints],
                "prev_action": prev_action,
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

    def run(self) -> DeployResult:
        cfg = self.config
        rng = np.random.default_rng(cfg.seed)
        period = 1.0 / cfg.rate_hz
        sections: dict[str, list[float]] = {s: [] for s in SECTIONS}
        periods: list[float] = []
        wake_late: list[float] = []
        episodes: list[EpisodeRecord] = []
        overruns = blind = 0
        stopped: str | None = None
        spec = self.decoder.spec
        if cfg.placements:  # before the arm moves: a bad placement is a config error, not a stop
            self._check_placements(self.io.new_contract(spec, cfg.rate_hz), cfg.placements)
        # the cyclic collector runs between episodes, never in a period; BLAS never waits on a
        # worker thread the loop's priority does not reach
        with QuietGC() as quiet, single_threaded_blas():
            try:
                for episode in range(cfg.episodes):
                    quiet.between()
                    contract = self.io.new_contract(spec, cfg.rate_hz)
                    if not cfg.dry_run:  # up, then open: a held cube drops, a new one is clear
                        self._home()
                    self.world.clear()  # sim and mock: last episode's objects off the table
                    percept = self._start(contract, episode, rng)
                    contract.begin(percept)
                    targets = self.arm.read_state().positions_rad.copy()
                    prev_action = np.zeros(self.decoder.n_actions)
                    invalid = 0
                    reason: str | None = None
                    sent: np.ndarray | None = None  # the last command, judged one period later
                    next_t = time.perf_counter()
                    last_start = next_t
                    slept = False  # the last period ended in a sleep to next_t
                    self._pipeline(True)
                    for step in range(self.steps):
                        start = time.perf_counter()
                        late = start - next_t if slept else math.nan
                        if slept:
                            wake_late.append(late)
                        if step > 0:
                            periods.append(start - last_start)
                            if start - last_start > period * (1 + cfg.overrun_warn_fraction):
                                overruns += 1
                                log.warning(
                                    "overrun: period %.1f ms (nominal %.1f ms)",
                                    (start - last_start) * 1e3,
                                    period * 1e3,
                                )
                        last_start = start
                        t0 = time.perf_counter()
                        state = self.arm.read_state()
                        t1 = time.perf_counter()
                        percept = self.perception.perceive(state, time.monotonic())
                        # the world now (truth or estimates): what the last period's command did
                        view = self._view(contract, percept, state.positions_rad, sent)
                        t2 = time.perf_counter()
                        if step > 0 and view is not None:
                            reason = contract.score(view, step - 1) or reason
                        if reason is not None:
                            log.warning("episode %d stopped: %s", episode, reason)
                            break
                        try:
                            obs = self._observation(
                                contract, percept, state.positions_rad, targets, prev_action, step
                            )
                            action = np.asarray(self.policy(obs), dtype=float)
                        except MissingEstimateError:
                            # an estimate went missing (a tracker lost its object): hold still and
                            # keep the watchdogs fed (the gripper action is absolute: keep it, or a
                            # held cube drops); a camera that stops delivering raises instead
                            invalid += 1
                            obs = np.full(self.builder.size, np.nan, dtype=np.float32)
                            action = np.zeros(self.decoder.n_actions)
                            action[self.decoder.spec.n_joints :] = prev_action[
                                self.decoder.spec.n_joints :
                            ]
                        t3 = time.perf_counter()
                        targets = self.decoder.decode(action, targets)
                        if cfg.dry_run:  # read and log, send nothing: the filter still judges it
                            last = self.arm.last_sent_rad
                            sent = self.arm.safety.filter(
                                targets, targets if last is None else last
                            )
                        else:
                            sent = self.arm.command(targets)  # safety once, inside command()
                        t4 = time.perf_counter()
                        prev_action = np.clip(action, -1.0, 1.0)
                        for name, dt in zip(
                            SECTIONS, (t1 - t0, t2 - t1, t3 - t2, t4 - t3), strict=True
                        ):
                            sections[name].append(dt)
                        self._log_period(
                            episode, step, t0, obs, action, targets, sent, state.positions_rad,
                            percept, view, periods[-1] if step > 0 else math.nan, sections, late,
                        )  # fmt: skip
                        if self.on_frame is not None:
                            self.on_frame()
                        next_t += period
                        slept = next_t - time.perf_counter() > 0
                        if slept:
                            _sleep_until(next_t)
                        else:
                            next_t = time.perf_counter()  # do not try to catch up: it bursts
                    else:  # the last command gets one whole period to act, then it is judged
                        _sleep_until(t4 + period)
                        reason = self._judge_last(contract, sent) or reason
                    self._pipeline(False)
                    blind += invalid
                    out = contract.outcome()
                    episodes.append(EpisodeRecord(out.success, out.distance_m, out.figures, reason))
                    self._hold()  # before any slow bookkeeping (video encoding): the watchdog waits
                    if self.on_episode is not None:
                        self.on_episode(episode, out.success, self.log.rows)
                    log.info(
                        "episode %d: success=%s distance %.4f m %s",
                        episode,
                        out.success,
                        out.distance_m,
                        out.figures,
                    )
                    self._hold()
            except KeyboardInterrupt:
                stopped = "interrupted (Ctrl-C or SIGTERM)"
                try:
                    self._safe_stop()
                except KeyboardInterrupt:  # a second Ctrl-C: torque off, keep the log
                    self._save_log()
                    raise
            except Exception as exc:  # any error: hold, park, torque off; keep the log
                stopped = f"{type(exc).__name__}: " + (str(exc).splitlines() or [""])[0]
                self._count_watchdog(exc)
                try:
                    self._safe_stop()
                finally:
                    self._save_log()  # even if a second Ctrl-C cuts the safe stop short
                raise
            else:
                self._park()
            finally:
                if self._sight is not None:
                    self._sight.close()
                    self._sight = None
        self._save_log()
        stats = self.arm.safety.stats
        return DeployResult(
            task=self.io.task,
            episodes=episodes,
            periods_s=periods,
            sections_s=sections,
            overruns=overruns,
            blind_periods=blind,
            stopped_early=stopped,
            safety_stats={
                "commands": stats.commands,
                "nonfinite": stats.nonfinite,
                "limit_clamped": stats.limit_clamped,
                "step_clamped": stats.step_clamped,
                **{k: v for k, v in vars(stats).items() if k.startswith("workspace")},
                **self.world_contacts(),
            },
            watchdog_trips=self._watchdog_trips,
            rate_hz=cfg.rate_hz,
            requested_episodes=cfg.episodes,
            wake_late_s=wake_late,
        )

    def world_contacts(self) -> dict[str, int]:
        """``{"table_contacts": n}`` where the world measures it (the mock arm's MuJoCo: physics
        steps with an arm link on the table), else nothing."""
        count = getattr(self.world, "table_contacts", None)
        n = count() if callable(count) else None
        return {} if n is None else {"table_contacts": int(n)}

    # ---- episode start ----------------------------------------------------------------------
    PLACEMENT_TRIES = 3  # a world that places objects may put one where the cameras miss it

    def _start(self, contract: DeployContract, episode: int, rng: np.random.Generator) -> Percept:
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

    @staticmethod
    def _check_placements(
        contract: DeployContract, placements: tuple[Mapping[str, Any], ...]
    ) -> None:
        """Every replayed placement names what the task places, with the contract's shapes."""
        drawn = contract.placement(np.random.default_rng(0))
        want = {k: np.shape(v) for k, v in drawn.items()}
        for i, placement in enumerate(placements):
            got = {k: np.shape(v) for k, v in placement.items()}
            if got != want:
                raise ConfigError(
                    f"placement {i} {got} does not match what task {contract.task!r} places: {want}"
                )
            for k, v in placement.items():
                if not np.all(np.isfinite(np.asarray(v, dtype=float))):
                    raise ConfigError(f"placement {i} {k!r} is not finite: {v}")

    MAX_PLACEMENT_DRAWS = 50

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
            self._hold()  # a render per draw: keep the watchdogs fed
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
        coast through that. A timeout stops the run with the contract's reason."""
        start = time.monotonic()
        deadline = start + self.config.start_timeout_s
        parked = self.config.dry_run
        while True:
            self._hold()
            now = time.monotonic()
            percept = self.perception.perceive(self.arm.read_state(), now)
            waiting = contract.ready(percept, now)
            if waiting is None and percept.tool_m is not None:
                if parked and not self.config.dry_run:
                    self.arm.home()
                    percept = self.perception.perceive(self.arm.read_state(), time.monotonic())
                return percept
            if now > deadline:
                raise DeployStopError(
                    f"episode {episode} never started: {waiting or 'no tool estimate'} after "
                    f"{self.config.start_timeout_s:.0f} s (objects {list(contract.objects)})"
                )
            if not parked and now - start > 0.5 * self.config.start_timeout_s:
                parked = True
                self.arm.park()
            time.sleep(0.02)

    # ---- success ----------------------------------------------------------------------------
    def _view(
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
            view = self._estimate_view(contract, percept, positions_rad, commanded_rad)
        return view

    def _judge_last(self, contract: DeployContract, sent: np.ndarray | None) -> str | None:
        """Judge the episode's last command on a view taken once it has had a period to act."""
        if sent is None:
            return None
        state = self.arm.read_state()
        percept = self.perception.perceive(state, time.monotonic())
        view = self._view(contract, percept, state.positions_rad, sent)
        reason = None if view is None else contract.score(view, self.steps - 1)
        if reason is not None:
            log.warning("episode stopped at its last period: %s", reason)
        return reason

    def _estimate_view(
        self,
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
        )

    def _log_period(
        self,
        episode: int,
        step: int,
        t0: float,
        obs: Any,
        action: np.ndarray,
        targets: np.ndarray,
        sent: np.ndarray,
        positions_rad: np.ndarray,
        percept: Percept,
        view: View | None,
        period_s: float,
        sections: Mapping[str, list[float]],
        wake_late_s: float = math.nan,
    ) -> None:
        flat = obs["observation"] if isinstance(obs, dict) else obs
        ee_seen = getattr(self.perception, "_ee_seen", None)
        extra: dict[str, Any] = {}
        for name in self.io.contract.objects:
            extra[f"{name}_est_m"] = percept.position(name)
            extra[f"{name}_blind_s"] = percept.blind_s(name)
            truth = view.objects.get(name) if view is not None and view.truth else None
            extra[f"{name}_true_m"] = truth
        if view is not None and view.truth:
            extra["grasped"] = math.nan if view.grasped is None else float(view.grasped)
        first = self.io.contract.objects[0]
        self.log.add(
            t_s=t0,
            episode=episode,
            step=step,
            obs=flat,
            action=action,
            targets_rad=targets,
            sent_rad=sent,
            joints_rad=positions_rad,
            ee_est_m=percept.tool_m,
            ee_seen=float(bool(ee_seen)) if ee_seen is not None else math.nan,
            goal_est_m=percept.position(first),
            true_tool_m=view.tool_m if view is not None and view.truth else None,
            period_s=period_s,
            wake_late_s=wake_late_s,
            **{f"{n}_s": sections[n][-1] for n in SECTIONS},
            **extra,
        )

    # ---- safe states --------------------------------------------------------------------------
    def _hold(self) -> None:
        """Between periods (no policy running) keep every watchdog fed: the arm does not move."""
        if self.arm.is_enabled and not self.config.dry_run:
            self.arm.hold()

    def _home(self) -> None:
        """Home in two moves: the joints first, the gripper as it is (a cube pressed against the
        table would wedge the fingers), then the gripper opens up high and a held cube drops."""
        n = self.decoder.spec.n_joints
        try:
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

    def _count_watchdog(self, exc: BaseException) -> None:
        if "watchdog" in str(exc):
            self._watchdog_trips += 1

    def _park(self) -> None:
        if self.config.dry_run:
            return
        try:
            self.arm.park()
            self.arm.disable()  # parked on its rest: torque off until the next run
        except HardwareError as exc:
            log.warning("park failed: %s", exc)
            self._safe_stop()

    def _pipeline(self, on: bool) -> None:
        """Pipelined commands (``SerialArm.set_pipelined``) in an episode's periods only: a
        period then waits for one serial round trip, its reading, not two."""
        setter = getattr(self.arm, "set_pipelined", None)
        if setter is not None and not self.config.dry_run:
            setter(on)

    def _safe_stop(self) -> None:
        """Hold, park if the arm still answers, then torque off (close does it)."""
        try:
            self._pipeline(False)
        except Exception as exc:  # the posted command's reply is lost: stop all the same
            log.warning("the last command's reply: %s", exc)
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

    def _save_log(self) -> None:
        if self.log_path is not None:
            try:
                self.log.save(self.log_path)
            except OSError as exc:
                log.error("could not write the trajectory log %s: %s", self.log_path, exc)


def _placement_str(placement: Mapping[str, Any]) -> str:
    return ", ".join(
        f"{k} {np.round(np.asarray(v, dtype=float), 3).tolist()}" for k, v in placement.items()
    )


def _sleep_until(deadline: float) -> None:
    """Sleep most of the way, then spin the last ~1 ms: time.sleep alone jitters by ~1 ms."""
    remaining = deadline - time.perf_counter()
    if remaining > 0.0015:
        time.sleep(remaining - 0.001)
    while time.perf_counter() < deadline:
        pass
