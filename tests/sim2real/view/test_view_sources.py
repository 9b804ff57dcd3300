"""The viewer's pieces without a deploy: the arm's strip against the spec's kinematics, camera
projection, overruns and replayed safety rules, and every source kind read from real writers."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from hardware.spec import load_spec
from sim2real.datasets.lerobot import (
    DatasetSchema,
    Feature,
    LeRobotWriter,
    arm_features,
    arm_frames,
)
from sim2real.errors import ConfigError
from sim2real.view.record import write_recording
from sim2real.view.scene import ViewCamera, arm_points_m, mock_rig_cameras
from sim2real.view.signals import signals
from sim2real.view.sources import LoadOptions, ViewRun, load_run

SPEC = load_spec()


def test_the_arm_strip_ends_at_the_specs_tool_and_bends_at_its_elbow() -> None:
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.uniform(SPEC.actuator_lower_rad, SPEC.actuator_upper_rad)
        strip = arm_points_m(SPEC, q)
        np.testing.assert_allclose(strip[-1], SPEC.forward_kinematics(q[:3]), atol=1e-12)
        np.testing.assert_allclose(strip[2], SPEC.elbow_position(q[:3]), atol=1e-12)
        np.testing.assert_allclose(strip[1], [0, 0, SPEC.links.base_height_m])
    assert np.isnan(arm_points_m(SPEC, np.full(4, np.nan))).all()


def test_a_camera_scaled_to_half_size_sees_a_point_at_half_the_pixels() -> None:
    left, _ = mock_rig_cameras()
    p = np.array([[0.15, 0.0, 0.05], [np.nan, 0.0, 0.0]])
    full = left.project(p)
    half = left.scaled((left.size_wh[0] // 2, left.size_wh[1] // 2)).project(p)
    assert 0 < full[0, 0] < left.size_wh[0] and 0 < full[0, 1] < left.size_wh[1]
    np.testing.assert_allclose(half[0], (full[0] + 0.5) / 2 - 0.5, atol=1e-9)
    assert np.isnan(full[1]).all()
    behind = ViewCamera("c", left.K, left.dist, left.size_wh, np.eye(4))
    assert np.isnan(behind.project(np.array([0.0, 0.0, -1.0]))).all()


def _run(n: int = 10, **extra: np.ndarray) -> ViewRun:
    q = np.tile(SPEC.actuator_home_rad, (n, 1))
    cols = {
        "joints_rad": q, "targets_rad": q.copy(), "sent_rad": q.copy(),
        "episode": np.zeros(n), "step": np.arange(n, dtype=float),
        "t_s": np.arange(n) * 0.05, "period_s": np.r_[np.nan, np.full(n - 1, 0.05)],
        **extra,
    }  # fmt: skip
    from sim2real.view.sources import _episodes

    return ViewRun("synthetic", "deploy-log", Path("x.npz"), cols, episodes=_episodes(cols, {}))


def test_overruns_and_the_filters_rules_are_found_period_by_period() -> None:
    run = _run()
    run.columns["period_s"][4] = 0.08  # 60 % long
    big = SPEC.safety.max_step_rad * 2
    run.columns["targets_rad"][2, 1] += big  # one step past the clamp
    run.columns["targets_rad"][6, 0] = SPEC.actuator_upper_rad[0] + 0.5  # past the limit
    run.columns["targets_rad"][8, 2] = np.nan
    sig = signals(run, SPEC)
    assert np.flatnonzero(sig.overrun).tolist() == [4]
    assert np.flatnonzero(sig.safety["step_clamped"]).tolist() == [2, 6]
    assert np.flatnonzero(sig.safety["limit_clamped"]).tolist() == [6]
    assert np.flatnonzero(sig.safety["nonfinite"]).tolist() == [8]
    assert sig.counts()["overrun"] == 1


def test_a_covariance_where_logged_is_drawn_as_an_ellipsoid(
    tmp_path: Path, rrd_counts: Callable[..., dict[str, int]]
) -> None:
    n = 6
    cov = np.tile(np.diag([1e-4, 4e-4, 9e-4]).ravel(), (n, 1))
    run = _run(n, target_est_m=np.tile([0.15, 0.0, 0.05], (n, 1)), target_cov_m2=cov)
    run = ViewRun(run.label, run.kind, run.path, run.columns, ("target",), run.episodes)
    write_recording([run], SPEC, tmp_path / "c.rrd")
    counts = rrd_counts(tmp_path / "c.rrd")
    assert counts["/synthetic/world/estimates/target/covariance:HalfSize3D"] == n
    assert counts["/synthetic/world/estimates/target:Position3D"] == n


def _save_log(path: Path, n: int, episode: int, objects: tuple[str, ...] = ("target",)) -> None:
    q = np.tile(SPEC.actuator_home_rad, (n, 1))
    cols: dict[str, np.ndarray] = {
        "t_s": np.arange(n) * 0.05, "episode": np.full(n, float(episode)),
        "step": np.arange(n, dtype=float), "joints_rad": q, "targets_rad": q, "sent_rad": q,
        "ee_est_m": np.tile([0.16, 0.0, 0.12], (n, 1)), "period_s": np.full(n, 0.05),
        "reward": -np.arange(n, dtype=float),
    }  # fmt: skip
    for name in objects:
        cols[f"{name}_est_m"] = np.tile([0.15, 0.0, 0.05], (n, 1))
    cols["goal_est_m"] = cols[f"{objects[0]}_est_m"]  # the deploy log's copy of the first
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **cols)


def test_a_finetune_folder_is_its_episodes_with_their_outcomes_and_stops(tmp_path: Path) -> None:
    out = tmp_path / "ft"
    for ep, n in ((0, 5), (1, 7)):
        _save_log(out / "episodes" / f"episode_{ep:05d}.npz", n, ep)
    state = {
        "episode_log": [{"episode": 0, "success": False, "kind": "train"},
                        {"episode": 1, "success": True, "kind": "eval"}],
        "stops": [{"episode": 1, "reason": "e-stop key"}],
        "interventions": [{"episode": 1, "action": "pause", "monotonic_s": 3.0}],
        "env_steps": 12,
    }  # fmt: skip
    (out / "finetune.json").write_text(json.dumps(state))
    (run,) = load_run(out)
    assert run.kind == "finetune" and run.n_periods == 12 and run.objects == ("target",)
    assert [(e.index, e.periods, e.success, e.note) for e in run.episodes] == [
        (0, 5, False, "train"),
        (1, 7, True, "eval"),
    ]
    assert [(e.period, e.kind) for e in run.events] == [(5, "stop"), (5, "intervention")]
    assert "reward" in run.columns


def test_an_adapt_folder_is_its_runs_before_and_after(tmp_path: Path) -> None:
    out = tmp_path / "adapt"
    out.mkdir()
    (out / "status.json").write_text("{}")
    with pytest.raises(ConfigError, match="has none of the logs"):
        load_run(out)
    _save_log(out / "zero_shot.npz", 4, 0)
    _save_log(out / "evaluate.npz", 6, 0)
    (out / "evaluate.json").write_text(json.dumps({"success_rate": 0.9}))
    runs = load_run(out)
    assert [(r.label, r.n_periods) for r in runs] == [("before", 4), ("after", 6)]
    assert runs[1].notes["figures"] == {"success_rate": 0.9}


def test_an_evaluate_dataset_reads_as_periods_with_reward_and_success(tmp_path: Path) -> None:
    joints = list(SPEC.actuator_names)
    extras = {"next.reward": Feature((1,)), "next.success": Feature((1,), "bool")}
    schema = DatasetSchema(
        fps=20, features=arm_features(joints, joints[:3], ["tool", "goal"], extras)
    )
    with LeRobotWriter(tmp_path / "ds", schema) as writer:
        for ep, n in enumerate((3, 4)):
            frames = arm_frames(
                np.zeros((n, 4)), np.zeros((n, 3)),
                {"tool": np.zeros((n, 3)), "goal": np.ones((n, 3))},
                {"next.reward": -np.ones(n), "next.success": np.arange(n) == n - 1},
            )  # fmt: skip
            writer.add_episode(frames, "move the tool tip to the target", ep == 1)
    (run,) = load_run(tmp_path / "ds")
    assert run.kind == "dataset" and run.n_periods == 7 and run.objects == ("goal",)
    assert [e.success for e in run.episodes] == [False, True] and run.frames is None
    assert run.columns["success"].tolist() == [0, 0, 1, 0, 0, 0, 1]
    np.testing.assert_allclose(run.columns["t_s"], np.arange(7) / 20)
    with pytest.raises(ConfigError, match="a dataset has its own"):
        load_run(tmp_path / "ds", LoadOptions(frames=tmp_path / "ds"))


def test_frames_that_do_not_pair_with_the_log_are_refused(tmp_path: Path) -> None:
    _save_log(tmp_path / "log.npz", 5, 0)
    joints = list(SPEC.actuator_names)
    schema = DatasetSchema(fps=20, features=arm_features(joints, joints[:3]))
    with LeRobotWriter(tmp_path / "ds", schema) as writer:
        writer.add_episode(arm_frames(np.zeros((4, 4)), np.zeros((4, 3))), "reach", True)
    with pytest.raises(ConfigError, match="episode 0 has 4 frames, the log's episode 0 5 periods"):
        load_run(tmp_path / "log.npz", LoadOptions(frames=tmp_path / "ds"))
