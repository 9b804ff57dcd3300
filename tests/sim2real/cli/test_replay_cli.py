"""``sim2real evaluate --record-dataset`` then ``sim2real replay`` through the CLI entry point."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import pytest

from sim2real.cli.main import main


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    tmp = tmp_path_factory.mktemp("replay")
    run = tmp / "run"
    args = ["train", "--env", "reach", "--algo", "ppo", "--steps", "128", "--run-dir", str(run)]
    args += ["--no-progress", "--set", "n_envs=2", "--set", "n_steps=64", "--set", "batch_size=64"]
    assert main(args) == 0
    out = tmp / "ds"
    rec = ["evaluate", str(run), "--episodes", "3", "--record-dataset", str(out)]
    rec += ["--dataset-image-size", "64x48", "--json"]
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(rec) == 0
    return out, json.loads(buf.getvalue())


def test_record_then_replay_summary(
    dataset: tuple[Path, dict], capsys: pytest.CaptureFixture[str]
) -> None:
    out, rec = dataset
    assert rec["dataset"] == str(out) and rec["episodes"] == 3
    assert main(["replay", str(out), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert (s["episodes"], s["frames"], s["fps"]) == (3, rec["frames"], 20)
    assert sum(s["episode_success"]) == rec["successes"]
    assert s["features"]["observation.images.cam_right"] == "video (48, 64, 3)"
    assert s["tasks"] == ["move the tool tip to the target"]
    assert main(["replay", str(out)]) == 0
    text = capsys.readouterr().out
    assert "episodes       3" in text and "observation.tool_pos" in text


def test_replay_one_episode(dataset: tuple[Path, dict], capsys: pytest.CaptureFixture[str]) -> None:
    out, _ = dataset
    capsys.readouterr()
    assert main(["replay", str(out), "--episode", "2", "--json"]) == 0
    ep = json.loads(capsys.readouterr().out)
    n = ep["length"]
    assert ep["video_frames"] == {
        "observation.images.cam_left": n,
        "observation.images.cam_right": n,
    }
    assert len(ep["frames"]["action"]) == n and len(ep["frames"]["observation.state"][0]) == 3
    assert main(["replay", str(out), "--episode", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("episode 2:") and len(lines) == 3 + n


def test_record_refuses_an_existing_folder_and_bad_input(
    dataset: tuple[Path, dict], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, _ = dataset
    run = out.parent / "run"
    capsys.readouterr()
    assert main(["evaluate", str(run), "--episodes", "1", "--record-dataset", str(out)]) == 2
    assert "exists" in capsys.readouterr().err
    bad = ["evaluate", str(run), "--episodes", "1", "--record-dataset", str(tmp_path / "x")]
    assert main([*bad, "--dataset-image-size", "33x10"]) == 2
    assert "image size '33x10'" in capsys.readouterr().err
    assert main([*bad, "--video", str(tmp_path / "v.mp4")]) == 2
    assert "conflicting flags" in capsys.readouterr().err
    assert main(["replay", str(tmp_path)]) == 2
    assert "not a LeRobot dataset" in capsys.readouterr().err
    assert main(["replay", str(out), "--episode", "9"]) == 2
    assert "episode 9 not in [0, 2]" in capsys.readouterr().err
