"""``sim2real compare`` stopped by SIGTERM, as a scheduler or a container stop does: the run in
flight in a worker keeps a checkpoint, no queued job starts, and the command exits 143."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from timescale import scaled

from sim2real.train import RunDir

TINY = ["--set", "n_envs=2", "--set", "n_steps=64", "--set", "batch_size=64", "--set", "n_epochs=1"]


# slow (CI runs it after the main suite): a signal's checkpoint and resume are judged in the fast
# suite on train itself (tests/sim2real/cli/test_train_cli.py), compare's files in test_compare.py
@pytest.mark.realtime
@pytest.mark.slow
def test_sigterm_keeps_the_checkpoint_of_the_run_in_flight(
    tmp_path: Path, spawn: Callable[..., subprocess.Popen[str]]
) -> None:
    out = tmp_path / "report"
    proc = spawn(
        [sys.executable, "-m", "sim2real", "compare", "--env", "reach", "--algos", "ppo",
         "--seeds", "2", "--workers", "1", "--steps", "1000000", "--out", str(out),
         *TINY, "--set", "checkpoint_every=256"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    first = RunDir(out / "runs" / "ppo-s0")
    deadline = time.monotonic() + scaled(180)
    while time.monotonic() < deadline and proc.poll() is None:
        if first.path.is_dir() and first.checkpoints():
            break
        time.sleep(0.2)
    assert first.path.is_dir() and first.checkpoints(), "no checkpoint appeared"
    proc.send_signal(signal.SIGTERM)  # to the parent only, not to its worker
    _, err = proc.communicate(timeout=scaled(180))
    assert proc.returncode == 143, err[-2000:]
    status = first.read_status()
    assert not status["finished"]
    latest = first.latest_checkpoint()
    assert latest is not None and latest.steps == status["steps_done"] >= 256
    assert not (out / "runs" / "ppo-s1").exists()  # the queued job never started
