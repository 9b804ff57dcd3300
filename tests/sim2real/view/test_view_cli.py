"""``sim2real view``: a real mock deploy's log and frames into a ``.rrd``, read back with Rerun's
own reader; two runs side by side; one-line errors for bad input and a missing extra."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from hardware.spec import load_spec
from sim2real.cli.main import main

REPO = Path(__file__).resolve().parents[3]
JOINTS = load_spec().actuator_names  # base_yaw, shoulder, elbow, gripper


def test_a_mock_deploy_log_with_its_frames_reads_back_entity_for_entity(
    mock_run: tuple[Path, Path],
    tmp_path: Path,
    rrd_counts: Callable[..., dict[str, int]],
    capsys: pytest.CaptureFixture[str],
) -> None:
    log_path, frames = mock_run
    log = np.load(log_path)
    n = len(log["joints_rad"])
    out = tmp_path / "mock.rrd"
    assert main(["view", str(log_path), "--frames", str(frames), "--save", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.splitlines()[-1])
    (run,) = summary["runs"]
    assert run["periods"] == n and run["episodes"] == 1 and run["frames"] == n
    assert run["markers"] > n  # the wrist plate in both cameras most of the time
    counts = rrd_counts(out)
    root = "/mock"
    for side in ("left", "right"):  # both cameras: every frame, markers and reprojections drawn
        assert counts[f"{root}/world/cameras/{side}/image:Blob"] == n  # JPEG-compressed frames
        assert counts[f"{root}/world/cameras/{side}/markers:LineStrip2D"] > 0
        assert counts[f"{root}/world/cameras/{side}/reprojection:Position2D"] == n
    for joint in JOINTS:  # command, safe command after the filter, reading
        for series in ("command", "sent", "reading"):
            assert counts[f"{root}/joints/{joint}/{series}:Scalar"] == n
    for piece in ("reading", "command", "sent"):  # the arm and its two ghosts, every period
        assert counts[f"{root}/world/arm/{piece}:LineStrip3D"] == n
    for group in ("estimates", "truth"):  # the mock world knows the truth
        for name in ("tool", "target"):
            assert counts[f"{root}/world/{group}/{name}:Position3D"] == n
    assert counts[f"{root}/objects/target/blind_s:Scalar"] == n
    finite_periods = int(np.isfinite(log["period_s"]).sum())  # the first period has none
    assert counts[f"{root}/timing/period_s:Scalar"] == finite_periods
    for section in ("read", "perceive", "infer", "command"):
        assert counts[f"{root}/timing/{section}_s:Scalar"] == n
    assert counts[f"{root}/events/log:Text"] >= 1  # the episode's verdict at its last period
    assert counts[f"{root}/outcome/episode_success:Scalar"] == 1  # judged, kept by the dataset
    overruns = run["events"]["overrun"]
    assert counts.get(f"{root}/events/overrun:Scalar", 0) == overruns
    assert set(run["events"]) >= {"overrun", "safety/step_clamped", "safety/workspace_clamped"}


def test_two_runs_sit_side_by_side_on_one_timeline(
    mock_run: tuple[Path, Path],
    sim_log: Path,
    tmp_path: Path,
    rrd_counts: Callable[..., dict[str, int]],
) -> None:
    out = tmp_path / "both.rrd"
    mock_log, _ = mock_run
    assert (
        main(["view", str(sim_log), str(mock_log), "--labels", "sim,mock", "--save", str(out)]) == 0
    )
    counts = rrd_counts(out)
    n_sim, n_mock = (len(np.load(p)["joints_rad"]) for p in (sim_log, mock_log))
    for label, n in (("sim", n_sim), ("mock", n_mock)):
        assert counts[f"/{label}/joints/shoulder/reading:Scalar"] == n
        assert counts[f"/{label}/world/arm/reading:LineStrip3D"] == n
        assert counts[f"/{label}/world/truth/target:Position3D"] == n
    # one "period" timeline: both runs start at period 0, so period k of one faces period k of
    # the other (the rows of the shorter run end first)
    import rerun.dataframe as rdf

    view = rdf.load_recording(str(out)).view(index="period", contents="/**")
    table = view.select("period", "/sim/joints/shoulder/reading:Scalar",
                        "/mock/joints/shoulder/reading:Scalar").read_all()  # fmt: skip
    periods = table.column("period").to_pylist()
    both = [
        p for p, a, b in zip(periods, table.column(1).to_pylist(), table.column(2).to_pylist(),
                             strict=True) if a is not None and b is not None
    ]  # fmt: skip
    assert both[0] == 0 and len(both) == min(n_sim, n_mock)


def test_a_run_that_is_none_of_the_kinds_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "notes.txt").write_text("hello")
    assert main(["view", str(tmp_path / "notes.txt"), "--save", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        len(err) == 1 and "none of the kinds the viewer reads" in err[0] and "notes.txt" in err[0]
    )
    assert main(["view", str(tmp_path / "missing.npz"), "--save", str(tmp_path / "x.rrd")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert not (tmp_path / "x.rrd").exists()


def test_labels_must_match_the_runs(
    sim_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["view", str(sim_log), "--labels", "a,b", "--save", str(tmp_path / "x.rrd")]
    assert main(args) == 2
    assert "--labels: 2 given for 1 runs" in capsys.readouterr().err
    args = ["view", str(sim_log), str(sim_log), "--save", str(tmp_path / "x.rrd")]
    assert main(args) == 2  # the same stem twice: two subtrees need two names
    assert "need different labels" in capsys.readouterr().err


CHILD = """
import importlib.abc, sys

class NoRerun(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] == "rerun":
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

sys.meta_path.insert(0, NoRerun())
from sim2real.cli.main import main
raise SystemExit(main(sys.argv[1:]))
"""


def test_without_rerun_the_view_extra_is_named_in_one_line(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    res = subprocess.run(
        [sys.executable, "-c", CHILD, "view", str(tmp_path / "x.npz"), "--save", "x.rrd"],
        capture_output=True, text=True, env=env, timeout=120, cwd=tmp_path,
    )  # fmt: skip
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert "needs the 'view' extra" in lines[0] and "pip install 'sim2real[view]'" in lines[0]
