"""Per-period signals a log implies but does not store: overruns, safety events, distances.

* Overruns are judged as the loop judges them: a period over the nominal one by more than
  ``OVERRUN_FRACTION`` (``LoopConfig.overrun_warn_fraction``). The nominal period is the run's
  rate where the source says it, else the median period.
* Safety events come from replaying the spec's own ``SafetyFilter`` on the logged commands: each
  period's ``targets_rad`` against the previous ``sent_rad`` (the reading, at an episode's
  first period). The log keeps only what was sent, rounded to servo units, so a replay says which
  rule acted (limit, step clamp, workspace guard, non-finite) where a difference would not.
* Distances from the tool to the first object, on the estimates and, on sim and mock, the truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hardware.errors import SafetyError
from hardware.safety import SafetyFilter
from hardware.spec import ArmSpec
from sim2real.errors import ConfigError
from sim2real.view.sources import ViewRun

OVERRUN_FRACTION = 0.2  # as LoopConfig.overrun_warn_fraction: the loop warns past it
SAFETY_EVENTS: tuple[str, ...] = ("nonfinite", "limit_clamped", "step_clamped", "workspace_clamped")


@dataclass(frozen=True)
class Signals:
    nominal_period_s: float
    overrun: np.ndarray  # (n,) bool
    safety: dict[str, np.ndarray] = field(default_factory=dict)  # event -> (n,) bool
    distance_m: dict[str, np.ndarray] = field(default_factory=dict)  # "estimate"/"truth" -> (n,)

    def counts(self) -> dict[str, int]:
        return {"overrun": int(self.overrun.sum())} | {
            k: int(v.sum()) for k, v in self.safety.items()
        }


def nominal_period_s(run: ViewRun) -> float:
    if run.rate_hz:
        return 1.0 / run.rate_hz
    periods = run.column("period_s")
    finite = periods[np.isfinite(periods)] if periods is not None else np.zeros(0)
    return float(np.median(finite)) if len(finite) else math.nan


def overruns(run: ViewRun, nominal_s: float) -> np.ndarray:
    periods = run.column("period_s")
    if periods is None or not math.isfinite(nominal_s):
        return np.zeros(run.n_periods, bool)
    with np.errstate(invalid="ignore"):
        return np.asarray(periods > nominal_s * (1.0 + OVERRUN_FRACTION))


def replay_safety(run: ViewRun, spec: ArmSpec) -> dict[str, np.ndarray]:
    """Which of the filter's rules acted in each period (empty when commands are not logged)."""
    targets, sent, joints = (run.column(k) for k in ("targets_rad", "sent_rad", "joints_rad"))
    if targets is None or sent is None or joints is None:
        return {}
    if targets.shape[1] != spec.n_actuators:
        raise ConfigError(
            f"run {run.label!r} commands {targets.shape[1]} actuators, the spec "
            f"{spec.n_actuators} ({', '.join(spec.actuator_names)}): give its --spec"
        )
    filt = SafetyFilter(spec)
    out = {k: np.zeros(run.n_periods, bool) for k in SAFETY_EVENTS}
    starts = {e.first_period for e in run.episodes}
    for k in range(run.n_periods):
        prev = joints[k] if k in starts or not np.all(np.isfinite(sent[k - 1])) else sent[k - 1]
        if not np.all(np.isfinite(prev)):
            continue
        before = dict(vars(filt.stats))
        try:
            filt.filter(targets[k], prev)
        except SafetyError:  # a command the filter refuses outright is non-finite (raise mode)
            out["nonfinite"][k] = True
            continue
        for key in SAFETY_EVENTS:
            out[key][k] = getattr(filt.stats, key) > before[key]
    return out


def distances(run: ViewRun) -> dict[str, np.ndarray]:
    if not run.objects:
        return {}
    first = run.objects[0]
    pairs = {
        "estimate": ("ee_est_m", f"{first}_est_m"),
        "truth": ("true_tool_m", f"{first}_true_m"),
    }
    out = {}
    for name, (tool_key, obj_key) in pairs.items():
        tool, obj = run.column(tool_key), run.column(obj_key)
        if tool is not None and obj is not None and tool.shape == obj.shape:
            out[name] = np.linalg.norm(tool - obj, axis=1)
    return out


def signals(run: ViewRun, spec: ArmSpec) -> Signals:
    nominal = nominal_period_s(run)
    return Signals(nominal, overruns(run, nominal), replay_safety(run, spec), distances(run))
