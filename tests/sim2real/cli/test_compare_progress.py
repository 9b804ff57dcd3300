"""``sim2real compare``'s bar reads the run dirs its workers write; quiet off a terminal."""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TextIO

import pytest

from sim2real.cli.compare import _steps_done, watch_runs
from sim2real.cli.main import main


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    runs = tmp_path_factory.mktemp("compare") / "runs"
    args = ["train", "--env", "reach", "--algo", "ppo", "--steps", "128"]
    args += ["--run-dir", str(runs / "ppo-s0"), "--no-progress", "--set", "n_envs=2"]
    args += ["--set", "n_steps=64", "--set", "batch_size=64"]
    assert main(args) == 0
    return runs


@pytest.fixture
def tty() -> Iterator[TextIO]:
    leader, follower = os.openpty()
    stream = os.fdopen(follower, "w")
    yield stream
    stream.close()
    os.close(leader)


def test_steps_done_reads_a_real_run(finished_run: Path) -> None:
    steps, finished = _steps_done(finished_run / "ppo-s0")
    assert steps >= 128 and finished
    assert _steps_done(finished_run / "not-started") == (0, False)


def test_bar_on_a_terminal(
    finished_run: Path,
    tty: TextIO,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.delenv("CI", raising=False)
    monkeypatch.setattr(sys, "stdout", tty)
    with watch_runs(finished_run, ["ppo-s0", "a2c-s0"], 128, enabled=True):
        pass  # the bar shows the final state on exit, however short the wait
    assert "runs done 1/2" in capsys.readouterr().err


def test_no_bar_in_ci(
    finished_run: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("CI", "true")
    with watch_runs(finished_run, ["ppo-s0"], 128, enabled=True):
        pass
    assert capsys.readouterr().err == ""
