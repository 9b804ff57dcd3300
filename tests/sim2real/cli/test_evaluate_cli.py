"""``sim2real evaluate`` and ``sim2real export`` through the CLI entry point."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from sim2real.cli.main import main

FIELDS = (
    "success_rate",
    "success_rate_wilson95",
    "mean_final_distance_m",
    "mean_episode_length",
    "mean_return",
)


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("cli") / "run"
    args = [
        "train",
        "--env",
        "reach",
        "--algo",
        "ppo",
        "--steps",
        "128",
        "--run-dir",
        str(path),
        "--no-progress",
        "--set",
        "n_envs=2",
        "--set",
        "n_steps=64",
        "--set",
        "batch_size=64",
    ]
    assert main(args) == 0
    return path


def test_evaluate_json_has_every_field(run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    assert main(["evaluate", str(run), "--episodes", "8", "--dr", "shifted", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for key in FIELDS:
        assert key in out
    assert out["episodes"] == 8 and out["dr"] == "shifted" and out["trained_dr"] == "default"
    assert out["seeds"]["held_out"] is True


def test_export_then_evaluate_the_exported_file(
    run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    capsys.readouterr()
    out_file = tmp_path / "policy.npz"
    assert main(["export", str(run), "--format", "numpy", "--out", str(out_file), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["observations"] == 1000 and res["max_abs_action_diff"] <= 1e-5
    assert main(["evaluate", str(out_file), "--episodes", "4", "--json"]) == 0
    from_file = json.loads(capsys.readouterr().out)
    assert main(["evaluate", str(run), "--episodes", "4", "--json"]) == 0
    from_run = json.loads(capsys.readouterr().out)
    assert from_file["success_rate"] == from_run["success_rate"]
    assert from_file["mean_final_distance_m"] == pytest.approx(
        from_run["mean_final_distance_m"], abs=1e-6
    )


def test_sweep_writes_csv_and_heatmap(
    run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    capsys.readouterr()
    args = [
        "evaluate",
        str(run),
        "--sweep",
        "--sweep-axis",
        "latency_steps=0,2",
        "--sweep-episodes",
        "2",
        "--out",
        str(tmp_path),
        "--json",
    ]
    assert main(args) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["cells"] == 2
    assert Path(res["csv"]).is_file() and Path(res["heatmap"]).is_file()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["evaluate", "{tmp}/missing"], "does not exist"),
        (["evaluate", "{tmp}"], "has no config.json: not a run dir"),
        (["evaluate", "{run}", "--dr", "wild"], "unknown DR preset 'wild'"),
        (
            ["evaluate", "{run}", "--sweep", "--video", "{tmp}/v.mp4"],
            "conflicting flags: --sweep and --video",
        ),
        (
            ["evaluate", "{run}", "--render", "opengl"],
            "unknown render mode 'opengl'; valid: human, none",
        ),
        (["evaluate", "{run}", "--episodes", "0"], "episodes 0 not in"),
        (["evaluate", "{run}", "--sweep-axis", "latency_steps"], "--sweep-axis needs --sweep"),
        (["evaluate", "{run}", "--sweep", "--sweep-axis", "wind"], "unknown sweep axis 'wind'"),
        (
            ["export", "{run}", "--format", "tflite"],
            "unknown export format 'tflite'; valid: numpy, onnx",
        ),
        (["export", "{tmp}/missing"], "does not exist"),
        (["compare", "--algos", "ppo"], "compare needs --out"),
        (["compare", "--algos", "ppo,bogus", "--out", "{tmp}/c"], "unknown algo 'bogus'"),
        (
            ["compare", "--algos", "ppo", "--backend", "slurm", "--out", "{tmp}/c"],
            "unknown backend 'slurm'",
        ),
        (
            ["demo", "--stages", "train,fly"],
            "unknown demo stage 'fly'; valid: deploy, evaluate, export, pick, train",
        ),
    ],
)
def test_bad_input_is_one_line_and_exit_2(
    run: Path, tmp_path: Path, args: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    capsys.readouterr()
    argv = [a.format(tmp=tmp_path, run=run) for a in args]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"sim2real {argv[0]}: error: ") and err.count("\n") == 1, err
    assert message in err


def test_corrupt_model_is_a_one_line_error(
    run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(run, broken)
    (broken / "model.zip").write_bytes(b"PK\x03\x04 not really a zip")
    capsys.readouterr()
    assert main(["evaluate", str(broken), "--episodes", "2"]) == 2
    err = capsys.readouterr().err
    assert "cannot load model.zip" in err and err.count("\n") == 1
