"""The fixed-rate deploy loop: N episodes of a policy on any arm, for any task.

The loop is a thin driver over ``session.ControlSession``, whose public steps are an episode
(begin, periods, judge the last command, end; safe stop, park) and one control period (sense →
observe → infer → act → pace). What the loop adds is the run around them: the policy call, the
run's exception policy, the per-run hooks (video frames, dataset episodes) and the result.

Every command passes the safety filter exactly once, inside ``Arm.command``. The loop never
waits for a camera: it takes the newest frame pair and the trackers predict to the command time.
On Ctrl-C or any error the arm holds, parks and goes torque-off, and the trajectory log is kept.
Success is judged as the env judges it, after the command has acted: period k on the world seen
at the start of period k+1, and the last period on one more view, a period after its command.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hardware.arm import ArmBase
from sim2real.deploy.clock import log
from sim2real.deploy.perception import Perception
from sim2real.deploy.policy_io import PolicyIO
from sim2real.deploy.realtime import QuietGC, single_threaded_blas
from sim2real.deploy.session import (
    LOG_KEYS,
    SECTIONS,
    ControlSession,
    DeployStopError,
    EpisodeRecord,
    LoopConfig,
    LoopLog,
)
from sim2real.envs.contract import MissingEstimateError

if TYPE_CHECKING:  # worlds import MuJoCo; the deploy profile runs without it
    from sim2real.deploy.worlds import World

__all__ = [
    "LOG_KEYS",
    "SECTIONS",
    "DeployLoop",
    "DeployResult",
    "DeployStopError",
    "EpisodeRecord",
    "LoopConfig",
    "LoopLog",
    "Policy",
]

Policy = Callable[[Any], np.ndarray]


def _percentile_ms(values: list[float], q: float) -> float:
    return float(np.percentile(values, q) * 1e3) if values else float("nan")


@dataclass(frozen=True)
class Spread:
    """A timing's spread in milliseconds (NaN where nothing was measured); ``max`` where kept."""

    p50: float
    p99: float
    max: float | None = None

    @classmethod
    def of(cls, values_s: list[float], with_max: bool = True) -> Spread:
        top = (float(max(values_s) * 1e3) if values_s else math.nan) if with_max else None
        return cls(_percentile_ms(values_s, 50), _percentile_ms(values_s, 99), top)

    def to_json(self) -> dict[str, float]:
        out = {"p50": self.p50, "p99": self.p99}
        return out if self.max is None else {**out, "max": self.max}


@dataclass(frozen=True)
class DeploySummary:
    """A deployment's figures: what ``sim2real deploy`` prints (``to_json``, at the CLI edge
    only) and what callers read by name."""

    task: str
    episodes: int
    success_rate: float
    mean_final_distance_m: float  # NaN: no episode ended with a finite distance
    task_figures: Mapping[str, float]  # the task's own: ``<key>_rate`` or ``mean_<key>``
    episode_stops: tuple[str, ...]  # why episodes ended early, one line each
    loop_hz: float
    period_jitter_ms: Spread
    wake_late_ms: Spread
    overruns: int
    blind_periods: int
    watchdog_trips: int
    sections_ms: Mapping[str, Spread]  # each section of the period: p50, p99
    safety: Mapping[str, int]
    stopped_early: str | None

    def __post_init__(self) -> None:
        if self.episodes < 0 or not 0.0 <= self.success_rate <= 1.0:
            raise ValueError(
                f"deploy summary: {self.episodes} episodes at success rate {self.success_rate}"
            )

    def to_json(self) -> dict[str, Any]:
        """The JSON ``sim2real deploy --json`` prints (its keys and their order are its format)."""
        return {
            "task": self.task,
            "episodes": self.episodes,
            "success_rate": self.success_rate,
            "mean_final_distance_m": self.mean_final_distance_m,
            "task_figures": dict(self.task_figures),
            "episode_stops": list(self.episode_stops),
            "loop_hz": self.loop_hz,
            "period_jitter_ms": self.period_jitter_ms.to_json(),
            "wake_late_ms": self.wake_late_ms.to_json(),
            "overruns": self.overruns,
            "blind_periods": self.blind_periods,
            "watchdog_trips": self.watchdog_trips,
            "sections_ms": {s: v.to_json() for s, v in self.sections_ms.items()},
            "safety": dict(self.safety),
            "stopped_early": self.stopped_early,
        }


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

    def _task_figures(self) -> dict[str, float]:
        """Each of the task's figures over the episodes: a flag's rate, a value's finite mean."""
        figures: dict[str, float] = {}
        for key in self.episodes[0].figures if self.episodes else ():
            values = [e.figures[key] for e in self.episodes if key in e.figures]
            if all(isinstance(v, bool | np.bool_) for v in values):
                figures[f"{key}_rate"] = float(np.mean(values))
            else:
                finite = [float(v) for v in values if math.isfinite(float(v))]
                figures[f"mean_{key}"] = float(np.mean(finite)) if finite else math.nan
        return figures

    def summary(self) -> DeploySummary:
        n = max(len(self.episodes), 1)
        periods = np.asarray(self.periods_s)
        jitter = np.abs(periods - 1.0 / self.rate_hz) if len(periods) else np.zeros(0)
        distances = [e.distance_m for e in self.episodes]
        return DeploySummary(
            task=self.task,
            episodes=len(self.episodes),
            success_rate=self.successes / n,
            mean_final_distance_m=float(np.nanmean(distances))
            if any(math.isfinite(d) for d in distances)
            else math.nan,
            task_figures=self._task_figures(),
            episode_stops=tuple(e.reason for e in self.episodes if e.reason),
            loop_hz=float(1.0 / periods.mean()) if len(periods) else math.nan,
            period_jitter_ms=Spread.of(list(jitter)),
            wake_late_ms=Spread.of(self.wake_late_s),
            overruns=self.overruns,
            blind_periods=self.blind_periods,
            watchdog_trips=self.watchdog_trips,
            sections_ms={s: Spread.of(v, with_max=False) for s, v in self.sections_s.items()},
            safety=self.safety_stats,
            stopped_early=self.stopped_early,
        )


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
        self.log = LoopLog()
        self.session = ControlSession(
            arm, perception, world, io, config, self.log, obs_keys, pipelined=True
        )
        self.arm, self.perception, self.world = arm, perception, world
        self.policy, self.io, self.config = policy, io, config
        self.steps = self.session.steps
        self.log_path = log_path
        self.on_frame = on_frame
        self.on_episode = on_episode  # (episode, success, the log's rows): dataset recording
        self._watchdog_trips = 0
        self._episodes: list[EpisodeRecord] = []
        self._blind = 0
        self._stopped: str | None = None

    def run(self) -> DeployResult:
        """Every episode; Ctrl-C is a safe stop (a second one: torque off, the log kept); any
        error holds, parks and goes torque off, keeps the log and is raised."""
        session, cfg = self.session, self.config
        rng = np.random.default_rng(cfg.seed)
        if cfg.placements:  # before the arm moves: a bad placement is a config error, not a stop
            session.check_placements()
        # the cyclic collector runs between episodes, never in a period; BLAS never waits on a
        # worker thread the loop's priority does not reach
        with QuietGC() as quiet, single_threaded_blas():
            try:
                for episode in range(cfg.episodes):
                    quiet.between()
                    self._episode(episode, rng)
            except KeyboardInterrupt:
                self._stopped = "interrupted (Ctrl-C or SIGTERM)"
                try:
                    session.safe_stop()
                except KeyboardInterrupt:  # a second Ctrl-C: torque off, keep the log
                    session.save_log(self.log_path)
                    raise
            except Exception as exc:  # any error: hold, park, torque off; keep the log
                self._stopped = f"{type(exc).__name__}: " + (str(exc).splitlines() or [""])[0]
                log.error("run stopped: %s", self._stopped)  # the one line the log keeps
                if "watchdog" in str(exc):
                    self._watchdog_trips += 1
                try:
                    session.safe_stop()
                finally:
                    session.save_log(self.log_path)  # even if a second Ctrl-C cuts it short
                raise
            else:
                session.park()
            finally:
                session.close()
        session.save_log(self.log_path)
        return self._result()

    def _episode(self, episode: int, rng: np.random.Generator) -> None:
        """Begin, run the periods until the last or a stop, judge, end."""
        session = self.session
        session.begin_episode(episode, rng)
        log.info("episode %d started", episode)
        for _ in range(self.steps):
            if not self._period():
                break
        else:  # the last command gets one whole period to act, then it is judged
            session.judge_last()
        record = session.end_episode()
        self._episodes.append(record)
        self._blind += session.blind_periods
        if self.on_episode is not None:
            self.on_episode(episode, record.success, self.log.rows)
        log.info(
            "episode %d: success=%s distance %.4f m %s",
            episode,
            record.success,
            record.distance_m,
            record.figures,
        )
        session.hold()

    def _period(self) -> bool:
        """One control period; False when the last command's view stopped the episode."""
        session = self.session
        sensed = session.sense()
        if session.reason is not None:
            log.warning("episode %d stopped: %s", session.episode, session.reason)
            return False
        try:
            obs = session.observe(sensed)
            action = np.asarray(self.policy(obs), dtype=float)
        except MissingEstimateError:  # a tracker lost its object: hold still this period
            obs, action = session.blind_period()
        session.act(action, sensed, obs)
        if self.on_frame is not None:
            self.on_frame()
        session.pace()
        return True

    def _result(self) -> DeployResult:
        session, stats = self.session, self.arm.safety.stats
        return DeployResult(
            task=self.io.task,
            episodes=self._episodes,
            periods_s=session.clock.periods_s,
            sections_s=session.sections_s,
            overruns=session.clock.overruns,
            blind_periods=self._blind,
            stopped_early=self._stopped,
            safety_stats={
                "commands": stats.commands,
                "nonfinite": stats.nonfinite,
                "limit_clamped": stats.limit_clamped,
                "step_clamped": stats.step_clamped,
                **{k: v for k, v in vars(stats).items() if k.startswith("workspace")},
                **session.world_contacts(),
            },
            watchdog_trips=self._watchdog_trips,
            rate_hz=self.config.rate_hz,
            requested_episodes=self.config.episodes,
            wake_late_s=session.clock.wake_late_s,
        )

    def world_contacts(self) -> dict[str, int]:
        """``{"table_contacts": n}`` where the world measures it, else nothing."""
        return self.session.world_contacts()
