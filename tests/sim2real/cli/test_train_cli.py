"""``sim2real train`` end to end: runs, resumes after a real SIGINT or SIGTERM, one-line
errors."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from timescale import scaled

from sim2real.cli.main import main
from sim2real.train import RunDir

TINY = ["--set", "n_envs=2", "--set", "n_steps=64", "--set", "batch_size=64", "--set", "n_epochs=1"]


def _train(run: Path, *extra: str) -> list[str]:
    return [
        "train",
        "--env",
        "reach",
        "--algo",
        "ppo",
        "--run-dir",
        str(run),
        "--no-progress",
        *TINY,
        *extra,
    ]


def test_train_then_resume_with_a_larger_budget(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "run"
    assert main([*_train(run, "--steps", "128", "--json")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["steps"] == 128 and out["run_dir"] == str(run)
    assert (
        main(["train", "--resume", "--run-dir", str(run), "--steps", "256", "--no-progress"]) == 0
    )
    assert RunDir(run).read_status()["steps_done"] == 256
    assert main(["train", "--resume", "--run-dir", str(run), "--no-progress"]) == 2
    assert "already finished 256 steps" in capsys.readouterr().err


@pytest.mark.realtime
@pytest.mark.parametrize(
    ("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)], ids=["SIGINT", "SIGTERM"]
)
def test_a_signal_leaves_a_checkpoint_that_resume_continues(
    tmp_path: Path, spawn: Callable[..., subprocess.Popen[str]], sig: int, code: int
) -> None:
    """Ctrl-C and SIGTERM (a scheduler, a container stop) both stop a run with a checkpoint at
    the step they arrived, exit 130/143, and ``--resume`` continues from it. The child gets
    default dispositions from ``spawn`` (a background job inherits SIGINT ignored) and is killed
    with its process group however the test ends."""
    run = tmp_path / "run"
    args = _train(run, "--steps", "1000000", "--set", "checkpoint_every=256")
    proc = spawn(
        [sys.executable, "-m", "sim2real", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    rd = RunDir(run)
    deadline = time.monotonic() + scaled(90)
    while not rd.checkpoints() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.2)
    assert rd.checkpoints(), "no checkpoint appeared"
    os.kill(proc.pid, sig)
    _, err = proc.communicate(timeout=scaled(120))
    assert proc.returncode == code, err
    assert f"interrupted ({'Ctrl-C' if code == 130 else 'SIGTERM'})" in err
    status = rd.read_status()
    assert not status["finished"]
    interrupted_at = rd.latest_checkpoint().steps  # type: ignore[union-attr]
    assert interrupted_at == status["steps_done"] >= 256
    target = interrupted_at + 128
    assert (
        main(["train", "--resume", "--run-dir", str(run), "--steps", str(target), "--no-progress"])
        == 0
    )
    status = rd.read_status()
    assert status["finished"] and status["segments"] == 2 and status["steps_done"] >= target


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["--env", "reach", "--algo", "trpo"],
            "unknown algo 'trpo'; valid: a2c, ddpg, distill, dqn, ppo, sac, td3",
        ),
        (["--env", "Arm3Fly", "--algo", "ppo"], "unknown env 'Arm3Fly'; valid:"),
        (["--env", "reach", "--algo", "ppo", "--her"], "--her needs an off-policy algo"),
        (["--env", "reach", "--algo", "sac", "--her"], "--her needs a goal-conditioned env"),
        (["--env", "reach", "--algo", "ppo", "--dr", "wild"], "unknown DR preset 'wild'"),
        (
            ["--env", "reach", "--algo", "ppo", "--set", "n_stepz=3"],
            "unknown ppo hyperparameter(s) ['n_stepz']",
        ),
        (
            ["--env", "reach", "--algo", "ppo", "--set", "n_steps"],
            "override 'n_steps' must look like KEY=VALUE",
        ),
        (
            ["--env", "reach", "--algo", "ppo", "--steps", "0"],
            "steps must be an integer >= 1, got 0",
        ),
        (
            ["--env", "reach", "--algo", "ppo", "--n-envs", "4", "--set", "n_envs=2"],
            "conflicting flags",
        ),
        (["--env", "reach", "--algo", "ppo", "--vec-env", "threads"], "unknown vec_env 'threads'"),
        (
            ["--env", "reach", "--algo", "ppo", "--set", "learning_rate=fast"],
            "learning_rate 'fast'",
        ),
        (["--env", "reach", "--algo", "ppo", "--preset", "nope"], "unknown preset 'nope'"),
        (["--algo", "ppo"], "train needs --env and --algo"),
        (
            ["--env", "reach", "--algo", "ppo", "--set", "batch_size=1"],
            "ppo rejected the configuration",
        ),
        (
            ["--env", "reach", "--algo", "ddpg", "--set", "action_noise=0.3"],
            "action_noise must be a mapping",
        ),
        (["--resume"], "does not exist"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(
    args: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["train", "--run-dir", str(tmp_path / "r"), "--no-progress", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("sim2real train: error: ") and err.count("\n") == 1
    assert message in err
    assert not (tmp_path / "r").exists()  # a refused run leaves no half-made folder


def test_run_dir_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "run"
    assert main([*_train(run, "--steps", "64")]) == 0
    capsys.readouterr()
    cases = [
        (_train(run, "--steps", "64"), "is not empty; pass --resume"),
        (
            ["train", "--resume", "--run-dir", str(run), "--algo", "ddpg"],
            "conflicting flags: --algo ddpg",
        ),
        (["train", "--resume", "--run-dir", str(tmp_path / "nope")], "does not exist"),
        (["train", "--resume"], "--resume needs --run-dir"),
        (["train", "--resume", "--run-dir", str(run), "--set", "gamma=0.5"], "--set cannot change"),
    ]
    for args, message in cases:
        assert main(args) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, err
    (run / "config.json").write_text("{ truncated")
    assert main(["train", "--resume", "--run-dir", str(run)]) == 2
    assert "corrupt config.json" in capsys.readouterr().err


def test_console_entry_point_reports_one_line() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "sim2real", "train", "--env", "reach", "--algo", "nope"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2
    assert out.stderr == (
        "sim2real train: error: unknown algo 'nope'; valid: a2c, ddpg, distill, dqn, ppo, sac, td3\n"
    )
