"""A deployment's figures are a typed value; JSON is made at the CLI's edge, in the format
``sim2real deploy --json`` has always printed (keys, order, values)."""

from __future__ import annotations

import json
import math

import pytest

from sim2real.deploy.loop import DeployResult, DeploySummary, Spread
from sim2real.deploy.session import EpisodeRecord


def _result() -> DeployResult:
    episodes = [
        EpisodeRecord(True, 0.004, {"grasped_ever": True, "max_lift_m": 0.05}, None),
        EpisodeRecord(False, math.nan, {"grasped_ever": False, "max_lift_m": math.nan}, "blind"),
    ]
    return DeployResult(
        task="pick", episodes=episodes, periods_s=[0.05, 0.052, 0.049, 0.05],
        sections_s={"read": [0.001, 0.002], "infer": [0.0005]}, overruns=1, blind_periods=2,
        stopped_early=None, safety_stats={"commands": 4, "clamped": 1}, watchdog_trips=0,
        rate_hz=20.0, requested_episodes=2, wake_late_s=[0.0001, 0.0003],
    )  # fmt: skip


def test_the_cli_json_keeps_its_format() -> None:
    s = _result().summary()
    assert isinstance(s, DeploySummary) and s.episodes == 2 and s.success_rate == 0.5
    assert s.mean_final_distance_m == pytest.approx(0.004)
    body = s.to_json()
    assert list(body) == [
        "task", "episodes", "success_rate", "mean_final_distance_m", "task_figures",
        "episode_stops", "loop_hz", "period_jitter_ms", "wake_late_ms", "overruns",
        "blind_periods", "watchdog_trips", "sections_ms", "safety", "stopped_early",
    ]  # fmt: skip
    assert body["task_figures"] == {"grasped_ever_rate": 0.5, "mean_max_lift_m": 0.05}
    assert body["episode_stops"] == ["blind"]
    assert list(body["period_jitter_ms"]) == ["p50", "p99", "max"]
    assert body["period_jitter_ms"]["max"] == pytest.approx(2.0)
    assert body["sections_ms"]["read"] == {"p50": pytest.approx(1.5), "p99": pytest.approx(1.99)}
    assert body["sections_ms"]["infer"] == {"p50": 0.5, "p99": 0.5}
    assert body["safety"] == {"commands": 4, "clamped": 1} and body["stopped_early"] is None
    json.dumps(body)  # plain JSON types only


def test_nothing_measured_is_nan_not_an_error() -> None:
    empty = DeployResult("reach", [], [], {}, 0, 0, "interrupted", {}, 0, 20.0, 3)
    s = empty.summary()
    assert s.episodes == 0 and s.success_rate == 0.0 and math.isnan(s.loop_hz)
    assert math.isnan(s.mean_final_distance_m) and s.period_jitter_ms.max is not None
    assert math.isnan(s.period_jitter_ms.max) and s.stopped_early == "interrupted"


def test_a_summary_out_of_range_is_refused_in_one_line() -> None:
    good = _result().summary()
    with pytest.raises(ValueError, match="3 episodes at success rate 1.5"):
        DeploySummary(**{**good.__dict__, "episodes": 3, "success_rate": 1.5})
    assert Spread(1.0, 2.0).to_json() == {"p50": 1.0, "p99": 2.0}
