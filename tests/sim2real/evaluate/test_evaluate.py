"""Evaluation on held-out seeds: the statistics, the figures, their determinism."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import imageio.v2 as imageio
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim2real.errors import ConfigError, Sim2RealError
from sim2real.evaluate import EvalTarget, evaluate, run_episodes, wilson_interval
from sim2real.evaluate.stats import mean_ci95
from sim2real.evaluate.sweep import parse_axes, pinned, plot_heatmap, run_sweep, write_csv
from sim2real.evaluate.video import record_video, view_human
from sim2real.train.config import EVAL_SEED_BASE

FIELDS = {
    "success_rate",
    "success_rate_wilson95",
    "mean_final_distance_m",
    "mean_episode_length",
    "mean_return",
}


def test_wilson_interval_matches_known_values() -> None:
    lo, hi = wilson_interval(5, 10)
    assert lo == pytest.approx(0.2366, abs=1e-4) and hi == pytest.approx(0.7634, abs=1e-4)
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(0.2775, abs=1e-4)
    lo, hi = wilson_interval(200, 200)
    assert hi == 1.0 and lo == pytest.approx(0.9812, abs=1e-4)


@given(st.integers(1, 500), st.data())
def test_wilson_interval_contains_the_estimate(n: int, data: st.DataObject) -> None:
    k = data.draw(st.integers(0, n))
    lo, hi = wilson_interval(k, n)
    assert 0.0 <= lo <= k / n <= hi <= 1.0


def test_mean_ci95_uses_student_t_over_seeds() -> None:
    m, lo, hi = mean_ci95([0.9, 1.0, 0.95])
    assert m - lo == pytest.approx(hi - m)
    assert m == pytest.approx(0.95)
    assert hi - m == pytest.approx(4.303 * 0.05 / np.sqrt(3), rel=1e-3)
    assert mean_ci95([0.7]) == (0.7, 0.7, 0.7)


def test_evaluate_reports_every_field_on_held_out_seeds(tiny_run: Path) -> None:
    target = EvalTarget.load(tiny_run)
    out = evaluate(target, episodes=6)
    assert set(out) >= FIELDS
    assert out["episodes"] == 6 and out["mean_episode_length"] == 50.0
    lo, hi = out["success_rate_wilson95"]
    assert lo <= out["success_rate"] <= hi
    assert out["seeds"]["first"] == EVAL_SEED_BASE
    assert not set(range(EVAL_SEED_BASE, EVAL_SEED_BASE + 6)) & set(target.training_seeds)
    assert out["dr"] == "default" and evaluate(target, episodes=2, dr="shifted")["dr"] == "shifted"
    clash = replace(target, training_seeds=(EVAL_SEED_BASE + 3,))
    with pytest.raises(ConfigError, match="were used in training"):
        clash.held_out_seeds(6)


def test_evaluation_measures_real_reaching(ik_target: Any) -> None:
    """A known-good IK controller succeeds; the same controller frozen (gain 0) does not."""
    seeds = ik_target.held_out_seeds(20)
    dr = ik_target.dr("none")
    good = run_episodes(ik_target.policy, ik_target.env_factory(dr), seeds)
    assert good.success_rate >= 0.9
    assert np.median([e.final_distance_m for e in good.episodes]) < 0.005
    frozen = type(ik_target.policy)(ik_target.policy.meta, gain=0.0)
    still = run_episodes(frozen, ik_target.env_factory(dr), seeds)
    assert still.success_rate <= 0.1
    assert all(e.ret < g.ret for e, g in zip(still.episodes, good.episodes, strict=True))


def test_results_do_not_depend_on_batching(tiny_run: Path) -> None:
    target = EvalTarget.load(tiny_run)
    seeds = target.held_out_seeds(5)
    a = run_episodes(target.policy, target.env_factory(target.train_dr), seeds, n_parallel=1)
    b = run_episodes(target.policy, target.env_factory(target.train_dr), seeds, n_parallel=5)
    for x, y in zip(a.episodes, b.episodes, strict=True):
        assert x.seed == y.seed and x.success == y.success
        assert x.final_distance_m == pytest.approx(y.final_distance_m, abs=1e-6)


def test_sweep_pins_each_axis_and_writes_csv_and_heatmap(ik_target: Any, tmp_path: Path) -> None:
    grid = parse_axes(["latency_steps=0,3", "actuator_gain=1.0,0.5"])
    cfg = pinned(ik_target.dr("default"), {"latency_steps": 3, "actuator_gain": 0.5})
    assert cfg["actuation"]["latency_steps"].low == cfg["actuation"]["latency_steps"].high == 3
    assert cfg["dynamics"]["actuator_gain_scale"].low == 0.5
    rows = run_sweep(ik_target, grid, episodes=6)
    assert [(r["latency_steps"], r["actuator_gain"]) for r in rows] == [
        (0, 1.0),
        (0, 0.5),
        (3, 1.0),
        (3, 0.5),
    ]
    assert rows[0]["success_rate"] > rows[2]["success_rate"]  # 3 steps of lag hurt the IK loop
    csv_path = write_csv(rows, tmp_path / "sweep.csv")
    assert csv_path.read_text().splitlines()[0].startswith("latency_steps,actuator_gain,episodes")
    png = plot_heatmap(rows, grid, tmp_path / "sweep.png", "test")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    three = parse_axes([])
    assert list(three) == ["latency_steps", "actuator_gain", "obs_noise_px"]
    with pytest.raises(Sim2RealError, match="unknown sweep axis 'wind'"):
        parse_axes(["wind=1,2"])


def test_video_has_one_frame_per_step_from_the_rig_camera(tiny_run: Path, tmp_path: Path) -> None:
    target = EvalTarget.load(tiny_run)
    seeds = target.held_out_seeds(1)
    path, result = record_video(
        target, tmp_path / "clip.mp4", target.train_dr, seeds, width=320, height=240
    )
    frames = imageio.mimread(path, memtest=False)
    assert len(frames) == 51  # the reset frame plus 50 control steps
    assert frames[0].shape == (240, 320, 3) and frames[-1].std() > 10
    assert result.n == 1
    with pytest.raises(ConfigError, match="must end in one of"):
        record_video(target, tmp_path / "clip.gif", target.train_dr, seeds)


def test_human_render_without_a_display_is_a_one_line_error(
    tiny_run: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    target = EvalTarget.load(tiny_run)
    with pytest.raises(Sim2RealError, match="needs a display"):
        view_human(target, target.train_dr, [EVAL_SEED_BASE])
