"""A fine-tune's results are typed values; JSON is made at the CLI's edge and in ``state.json``,
in the format ``sim2real finetune --json`` has always printed (keys, order, values)."""

from __future__ import annotations

import json
import math

import pytest

from sim2real.finetune.results import ArmEndState, EvalFigures, FinetuneSummary, LoopFigures

SUMMARY_KEYS = [
    "event", "out", "algo", "noise_std", "relabel", "source", "backend", "plant", "episodes",
    "episodes_this_run", "env_steps", "arm_s", "success_last_n", "success_window", "evals",
    "learner_updates", "actor_weight_updates", "loop", "safety", "arm_end", "interventions",
    "checkpoint", "stopped",
]  # fmt: skip


def _summary(**changes: object) -> FinetuneSummary:
    fields = dict(
        out="runs/ft", algo="ddpg", noise_std=0.1, relabel=0.5, source="reach-ddpg",
        backend="mock", plant=None, episodes=3, episodes_this_run=2, env_steps=120,
        arm_s=9.25, success_last_n=math.nan, success_window=20,
        evals=(EvalFigures(0.05, 1, 2, 3, 0.5, (0.0945, 0.9055)),),
        learner_updates=40, actor_weight_updates=2,
        loop=LoopFigures(19.98, 0.4, 1.6, 1, 0, ("watchdog: no command",)),
        safety={"commands": 120, "clamped": 3}, arm_end=ArmEndState(False, (0.0, -1.1, 2.0), 0.02),
        interventions=0, checkpoint="step_120.zip", stopped=None,
    )  # fmt: skip
    fields.update(changes)
    return FinetuneSummary(**fields)  # type: ignore[arg-type]


def test_the_summary_json_keeps_its_format() -> None:
    body = _summary().to_json()
    assert list(body) == SUMMARY_KEYS
    assert json.dumps(body) == (
        '{"event": "summary", "out": "runs/ft", "algo": "ddpg", "noise_std": 0.1, '
        '"relabel": 0.5, "source": "reach-ddpg", "backend": "mock", "plant": null, '
        '"episodes": 3, "episodes_this_run": 2, "env_steps": 120, "arm_s": 9.25, '
        '"success_last_n": NaN, "success_window": 20, "evals": [{"arm_min": 0.05, '
        '"successes": 1, "n": 2, "end_episode": 3, "success": 0.5, "wilson95": [0.0945, '
        '0.9055]}], "learner_updates": 40, "actor_weight_updates": 2, "loop": {"rate_hz": '
        '19.98, "period_jitter_ms_p50": 0.4, "period_jitter_ms_p99": 1.6, "late_periods": 1, '
        '"watchdog_trips": 0, "recovered_estops": ["watchdog: no command"]}, "safety": '
        '{"commands": 120, "clamped": 3}, "arm_end": {"torque_on": false, "joints_rad": [0.0, '
        '-1.1, 2.0], "park_error_rad": 0.02}, "interventions": 0, "checkpoint": '
        '"step_120.zip", "stopped": null}'
    )


def test_where_the_arm_ended_keeps_its_two_shapes() -> None:
    assert ArmEndState(True, read_error="not connected").to_json() == {
        "torque_on": True,
        "read_error": "not connected",
    }
    assert list(ArmEndState(False, (0.1,), 0.3).to_json()) == [
        "torque_on",
        "joints_rad",
        "park_error_rad",
    ]
    assert _summary(arm_end=None).to_json()["arm_end"] == {}  # the env did not close


def test_impossible_results_are_refused_in_one_line() -> None:
    with pytest.raises(ValueError, match="exactly one"):
        ArmEndState(False, (0.1,), 0.3, read_error="gone")
    with pytest.raises(ValueError, match="exactly one"):
        ArmEndState(False, (0.1,))
    with pytest.raises(ValueError, match="3 successes in 2 episodes"):
        EvalFigures(0.0, 3, 2, None, 1.5, (0.0, 1.0))
    with pytest.raises(ValueError, match="4 episodes this run of 3"):
        _summary(episodes_this_run=4)
