"""The fixed-rate deploy loop: read → perceive → observe → infer → safety → command.

One loop serves every backend. What differs between them lives behind three small interfaces:
the ``Arm`` (MuJoCo, the emulator over a pty, a real bus), a ``Perception`` (ground truth with the
sensor model, or cameras → detect → triangulate → Kalman) and a ``World`` (places the target and,
where it can, judges success from ground truth). The observation is built by the same
``ObservationBuilder`` and the action decoded by the same ``ActionDecoder`` as in training.

On Ctrl-C or any error the arm holds, parks and goes torque-off, and the trajectory log is kept.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from hardware.arm import ArmBase, ArmState
from hardware.errors import HardwareError
from sim2real.errors import ConfigError
from sim2real.observation import ActionDecoder, ObservationBuilder, command_readings

log = logging.getLogger(__name__)

SECTIONS = ("read", "perceive", "infer", "safety", "command")
Policy = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Percept:
    """Position estimates in the base frame; ``None`` where nothing usable was seen."""

    ee_m: np.ndarray | None
    goal_m: np.ndarray | None


class Perception(Protocol):
    def reset(self) -> None: ...

    def perceive(self, state: ArmState, timestamp_s: float) -> Percept: ...

    def close(self) -> None: ...


class World(Protocol):
    """What is out there besides the arm: the target, and the truth where there is one."""

    def new_episode(self, rng: np.random.Generator) -> None: ...

    def success(self, percept: Percept) -> tuple[bool, float]:
        """(success, distance_m) at the end of an episode."""
        ...


@dataclass(frozen=True)
class LoopConfig:
    rate_hz: float = 20.0
    episodes: int = 10
    episode_steps: int = 50
    seed: int = 1_000_000  # held out: training seeds are small integers
    dry_run: bool = False
    success_threshold_m: float = 0.01
    overrun_warn_fraction: float = 0.2  # warn when a period runs 20 % long

    def __post_init__(self) -> None:
        if not 0.5 <= self.rate_hz <= 500:
            raise ConfigError(f"rate_hz {self.rate_hz} not in [0.5, 500]")
        if self.episodes < 1 or self.episode_steps < 1:
            raise ConfigError(
                f"episodes ({self.episodes}) and episode_steps ({self.episode_steps}) must be >= 1"
            )


@dataclass
class LoopLog:
    """Everything per period, for replay and sysid (saved as npz)."""

    rows: dict[str, list[Any]] = field(
        default_factory=lambda: {
            k: []
            for k in (
                "t_s",
                "episode",
                "step",
                "obs",
                "action",
                "targets_rad",
                "sent_rad",
                "joints_rad",
                "ee_est_m",
                "goal_est_m",
                "period_s",
                *(f"{s}_s" for s in SECTIONS),
            )
        }
    )

    def add(self, **values: Any) -> None:
        for key, value in values.items():
            self.rows[key].append(value)

    def save(self, path: Path) -> Path:
        from hardware.atomic import atomic_write_bytes

        arrays = {}
        for key, values in self.rows.items():
            if values:
                arrays[key] = np.asarray(
                    [np.full(3, np.nan) if v is None else v for v in values], dtype=float
                )
        import io

        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        atomic_write_bytes(path, buf.getvalue())
        return path


def _percentile_ms(values: list[float], q: float) -> float:
    return float(np.percentile(values, q) * 1e3) if values else float("nan")


@dataclass
class DeployResult:
    episodes: int
    successes: int
    final_distances_m: list[float]
    periods_s: list[float]
    sections_s: dict[str, list[float]]
    overruns: int
    blind_periods: int  # periods without a usable marker estimate (arm held still)
    stopped_early: str | None
    safety_stats: dict[str, int]
    rate_hz: float

    def summary(self) -> dict[str, Any]:
        n = max(len(self.final_distances_m), 1)
        periods = np.asarray(self.periods_s)
        nominal = 1.0 / self.rate_hz
        jitter = np.abs(periods - nominal) if len(periods) else np.zeros(0)
        return {
            "episodes": len(self.final_distances_m),
            "success_rate": self.successes / n,
            "mean_final_distance_m": float(np.mean(self.final_distances_m))
            if self.final_distances_m
            else math.nan,
            "loop_hz": float(1.0 / periods.mean()) if len(periods) else math.nan,
            "period_jitter_ms": {
                "p50": _percentile_ms(list(jitter), 50),
                "p99": _percentile_ms(list(jitter), 99),
                "max": float(jitter.max() * 1e3) if len(jitter) else math.nan,
            },
            "overruns": self.overruns,
            "blind_periods": self.blind_periods,
            "sections_ms": {
                s: {"p50": _percentile_ms(v, 50), "p99": _percentile_ms(v, 99)}
                for s, v in self.sections_s.items()
            },
            "safety": self.safety_stats,
            "stopped_early": self.stopped_early,
        }


class DeployLoop:
    """Runs ``policy`` on ``arm`` for N episodes at a fixed rate."""

    def __init__(
        self,
        arm: ArmBase,
        perception: Perception,
        world: World,
        policy: Policy,
        builder: ObservationBuilder,
        decoder: ActionDecoder,
        config: LoopConfig,
        log_path: Path | None = None,
        on_frame: Callable[[], None] | None = None,
    ) -> None:
        self.arm, self.perception, self.world = arm, perception, world
        self.policy, self.builder, self.decoder = policy, builder, decoder
        self.config = config
        self.log_path = log_path
        self.log = LoopLog()
        self.on_frame = on_frame
        self._n_obs_joints = builder.fields[0].size

    def run(self) -> DeployResult:
        cfg = self.config
        rng = np.random.default_rng(cfg.seed)
        period = 1.0 / cfg.rate_hz
        sections: dict[str, list[float]] = {s: [] for s in SECTIONS}
        periods: list[float] = []
        distances: list[float] = []
        successes = overruns = blind = 0
        stopped: str | None = None
        try:
            # Warm-up before torque is on: the first frame creates renderers / opens cameras,
            # which would otherwise starve the host watchdog in the first period.
            self.perception.perceive(self.arm.read_state(), time.perf_counter())
            for episode in range(cfg.episodes):
                self.world.new_episode(rng)
                self.perception.reset()
                self._feed()
                # Look before moving: the arm at home may hide a target near it.
                self.perception.perceive(self.arm.read_state(), time.perf_counter())
                self._feed()
                if not cfg.dry_run:
                    self.arm.home()
                targets = self.arm.read_state().positions_rad.copy()
                prev_action = np.zeros(self.decoder.n_actions)
                invalid = 0  # periods without estimates this episode (reported)
                percept = Percept(None, None)
                next_t = time.perf_counter()
                last_start = next_t
                for step in range(cfg.episode_steps):
                    start = time.perf_counter()
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
                    percept = self.perception.perceive(state, t1)
                    t2 = time.perf_counter()
                    if percept.ee_m is None or percept.goal_m is None:
                        # Markers out of view: hold still (and keep the watchdogs fed). A camera
                        # that stops delivering raises from the frame source instead.
                        invalid += 1
                        action = np.zeros(self.decoder.n_actions)
                        obs = np.full(self.builder.size, np.nan, dtype=np.float32)
                    else:
                        obs = self.builder.build(
                            {
                                "joint_pos": state.positions_rad[: self._n_obs_joints],
                                "joint_target": targets[: self._n_obs_joints],
                                "ee_pos": percept.ee_m,
                                "goal_pos": percept.goal_m,
                                "goal_delta": percept.goal_m - percept.ee_m,
                                "prev_action": prev_action,
                                **command_readings(self.decoder.spec, targets, percept.goal_m),
                            }
                        )
                        action = np.asarray(self.policy(obs), dtype=float)
                    t3 = time.perf_counter()
                    targets = self.decoder.decode(action, targets)
                    last = self.arm.last_sent_rad
                    safe = self.arm.safety.filter(targets, targets if last is None else last)
                    t4 = time.perf_counter()
                    sent = safe if cfg.dry_run else self.arm.command(safe)
                    t5 = time.perf_counter()
                    prev_action = np.clip(action, -1.0, 1.0)
                    for name, dt in zip(
                        SECTIONS, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4), strict=True
                    ):
                        sections[name].append(dt)
                    self.log.add(
                        t_s=t0,
                        episode=episode,
                        step=step,
                        obs=obs,
                        action=action,
                        targets_rad=targets,
                        sent_rad=sent,
                        joints_rad=state.positions_rad,
                        ee_est_m=percept.ee_m,
                        goal_est_m=percept.goal_m,
                        period_s=periods[-1] if step > 0 else math.nan,
                        **{f"{n}_s": sections[n][-1] for n in SECTIONS},
                    )
                    if self.on_frame is not None:
                        self.on_frame()
                    next_t += period
                    sleep = next_t - time.perf_counter()
                    if sleep > 0:
                        _sleep_until(next_t)
                    else:
                        next_t = time.perf_counter()  # do not try to catch up: it bursts
                blind += invalid
                ok, dist = self.world.success(percept)
                successes += int(ok)
                distances.append(dist)
                log.info("episode %d: success=%s final distance %.4f m", episode, ok, dist)
        except KeyboardInterrupt:
            stopped = "interrupted (Ctrl-C)"
            self._safe_stop()
        except Exception as exc:  # any error: hold, park, torque off; keep the log
            stopped = f"{type(exc).__name__}: {exc}"
            self._safe_stop()
            self._save_log()
            raise
        else:
            self._park()
        self._save_log()
        stats = self.arm.safety.stats
        return DeployResult(
            episodes=len(distances),
            successes=successes,
            final_distances_m=distances,
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
            },
            rate_hz=cfg.rate_hz,
        )

    def _feed(self) -> None:
        """Between episodes (no control period running) keep the host watchdog fed by
        re-sending the held targets: the arm does not move."""
        if self.arm.is_enabled and not self.config.dry_run:
            self.arm.hold()

    def _park(self) -> None:
        if self.config.dry_run:
            return
        try:
            self.arm.park()
            self.arm.disable()  # parked on its rest: torque off until the next run
        except HardwareError as exc:
            log.warning("park failed: %s", exc)
            self._safe_stop()

    def _safe_stop(self) -> None:
        """Hold, park if the arm still answers, then torque off (close does it)."""
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


def _sleep_until(deadline: float) -> None:
    """Sleep most of the way, then spin the last ~1 ms: time.sleep alone jitters by ~1 ms."""
    remaining = deadline - time.perf_counter()
    if remaining > 0.0015:
        time.sleep(remaining - 0.001)
    while time.perf_counter() < deadline:
        pass
