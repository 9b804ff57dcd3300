"""What a fine-tune returns, as typed values: the summary ``finetune()`` ends with, its loop
and evaluation figures, and where the arm was left. JSON is made only where it is printed or
written (``to_json``: the CLI's ``--json`` line, ``state.json``'s stops), in the format the
fine-tune has always written: the same keys, in the same order, with the same values."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class ArmEndState:
    """Where ``ArmEnv.close`` left the arm, read before the port closed: the joints and their
    distance from park, or why they could not be read."""

    torque_on: bool
    joints_rad: tuple[float, ...] | None = None  # the joints (not the gripper), read back
    park_error_rad: float | None = None  # the largest joint's distance from the park pose
    read_error: str | None = None  # one line: why the joints could not be read

    def __post_init__(self) -> None:
        read = self.joints_rad is not None and self.park_error_rad is not None
        partly = (self.joints_rad is None) != (self.park_error_rad is None)
        if partly or read == (self.read_error is not None):
            raise ValueError(
                f"arm end state: joints {self.joints_rad} and park error {self.park_error_rad}, "
                f"or a read error ({self.read_error!r}): exactly one"
            )

    def to_json(self) -> dict[str, Any]:
        """The ``arm_end`` object of the summary and of a stop."""
        out: dict[str, Any] = {"torque_on": self.torque_on}
        if self.read_error is not None:
            out["read_error"] = self.read_error
            return out
        out["joints_rad"] = list(self.joints_rad or ())
        out["park_error_rad"] = self.park_error_rad
        return out


@dataclass(frozen=True)
class EvalFigures:
    """One evaluation block: the deterministic actor's episodes from ``arm_min`` of arm time."""

    arm_min: float  # arm time when the block began, in minutes
    successes: int
    n: int  # its episodes so far
    end_episode: int | None  # the episode count when it ended (None: not finished)
    success: float  # successes / n (NaN before its first episode)
    wilson95: tuple[float, float]

    def __post_init__(self) -> None:
        if not 0 <= self.successes <= self.n:
            raise ValueError(f"eval block: {self.successes} successes in {self.n} episodes")

    def to_json(self) -> dict[str, Any]:
        return {
            "arm_min": self.arm_min,
            "successes": self.successes,
            "n": self.n,
            "end_episode": self.end_episode,
            "success": self.success,
            "wilson95": list(self.wilson95),
        }


@dataclass(frozen=True)
class LoopFigures:
    """The control loop while it learned: its rate, jitter against the nominal period, late
    periods and the e-stops it recovered from."""

    rate_hz: float  # NaN: no period measured
    period_jitter_ms_p50: float
    period_jitter_ms_p99: float
    late_periods: int
    watchdog_trips: int
    recovered_estops: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        return {
            "rate_hz": self.rate_hz,
            "period_jitter_ms_p50": self.period_jitter_ms_p50,
            "period_jitter_ms_p99": self.period_jitter_ms_p99,
            "late_periods": self.late_periods,
            "watchdog_trips": self.watchdog_trips,
            "recovered_estops": list(self.recovered_estops),
        }


@dataclass(frozen=True)
class FinetuneSummary:
    """What ``finetune()`` returns, also after an e-stop or a timeout (``stopped`` says why)."""

    out: str
    algo: str
    noise_std: float
    relabel: float
    source: str
    backend: str
    plant: str | None
    episodes: int  # all runs of this folder
    episodes_this_run: int
    env_steps: int
    arm_s: float
    success_last_n: float  # NaN: no training episode yet
    success_window: int
    evals: tuple[EvalFigures, ...]
    learner_updates: int
    actor_weight_updates: int
    loop: LoopFigures
    safety: Mapping[str, int]
    arm_end: ArmEndState | None  # None: the env did not close cleanly
    interventions: int
    checkpoint: str | None
    stopped: str | None  # None: it ran its budget

    def __post_init__(self) -> None:
        if self.episodes_this_run > self.episodes or self.env_steps < 0:
            raise ValueError(
                f"fine-tune summary: {self.episodes_this_run} episodes this run of "
                f"{self.episodes}, {self.env_steps} env steps"
            )
        if not (math.isfinite(self.arm_s) and self.arm_s >= 0):
            raise ValueError(f"fine-tune summary: arm time {self.arm_s} s")

    def to_json(self) -> dict[str, Any]:
        """The line ``sim2real finetune --json`` ends with (its keys and order are its format)."""
        return {
            "event": "summary",
            "out": self.out,
            "algo": self.algo,
            "noise_std": self.noise_std,
            "relabel": self.relabel,
            "source": self.source,
            "backend": self.backend,
            "plant": self.plant,
            "episodes": self.episodes,
            "episodes_this_run": self.episodes_this_run,
            "env_steps": self.env_steps,
            "arm_s": self.arm_s,
            "success_last_n": self.success_last_n,
            "success_window": self.success_window,
            "evals": [e.to_json() for e in self.evals],
            "learner_updates": self.learner_updates,
            "actor_weight_updates": self.actor_weight_updates,
            "loop": self.loop.to_json(),
            "safety": dict(self.safety),
            "arm_end": {} if self.arm_end is None else self.arm_end.to_json(),
            "interventions": self.interventions,
            "checkpoint": self.checkpoint,
            "stopped": self.stopped,
        }
