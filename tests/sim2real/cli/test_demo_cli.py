"""``sim2real demo``: named stages end to end on a tiny budget."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from sim2real.cli import demo
from sim2real.cli.main import main


def test_demo_runs_every_stage_and_replaces_only_its_own_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "demo"
    args = [
        "demo",
        "--out",
        str(out),
        "--steps",
        "128",
        "--episodes",
        "4",
        "--no-progress",
        "--json",
        "--stages",
        "train,evaluate,export",  # the mock deployment is covered by tests/sim2real/deploy
    ]
    assert main(args) == 0
    res = json.loads(capsys.readouterr().out)
    assert [s.name for s in demo.STAGES] == ["train", "evaluate", "export", "deploy", "pick"]
    assert list(res["stages"]) == ["train", "evaluate", "export"]
    assert res["stages"]["train"]["steps"] >= 128
    ev = res["stages"]["evaluate"]
    assert ev["default"]["episodes"] == 4 and "shifted" in ev
    assert res["stages"]["export"]["max_abs_action_diff"] <= 1e-5
    assert (out / "run" / "model.zip").is_file() and (out / "run" / "policy.onnx").is_file()
    assert json.loads((out / demo.DEMO_RESULTS).read_text()) == res  # the figures are kept
    table = demo.summary_table(res["stages"], res["total_s"]).splitlines()
    rows = [line.split("|")[1].strip() for line in table if line.startswith("|")]
    assert rows == ["stage", "train", "evaluate", "export", "total"]
    assert main(args) == 0  # a second demo replaces the first
    capsys.readouterr()
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("keep me")
    assert main(["demo", "--out", str(other), "--steps", "64", "--no-progress"]) == 2
    assert "is not a demo folder" in capsys.readouterr().err
    assert (other / "notes.txt").read_text() == "keep me"


def test_demo_ends_with_a_human_table(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["demo", "--out", str(tmp_path / "demo"), "--steps", "64", "--stages", "train"]
    assert main(args) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("== train:")
    table = [line for line in out if line.startswith(("|", "+"))]
    assert table[0] == table[-1] and set(table[0]) == {"+", "-"}
    assert any(line.startswith("| train ") and "PPO Arm3Reach-v0" in line for line in table)
    assert any(line.startswith("| total ") for line in table)
    assert "results.json" in out[-1]


@pytest.mark.slow
def test_default_demo_reaches_a_decent_success(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["demo", "--out", str(tmp_path / "demo"), "--no-progress", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["stages"]["evaluate"]["default"]["success_rate"] >= 0.7
