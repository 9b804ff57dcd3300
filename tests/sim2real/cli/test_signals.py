"""SIGTERM is Ctrl-C for the long commands: the handler itself, and ``deploy`` over the mock arm
stopped by a real SIGTERM (train's checkpoint case is in test_train_cli.py)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from timescale import scaled  # type: ignore[import-not-found]

from sim2real.cli.main import COMMANDS
from sim2real.cli.signals import Terminated, exit_code_for, interrupts_as_keyboard


def _deliver(sig: int) -> None:
    """Send ``sig`` to this process and give the interpreter a bytecode boundary to run the
    handler at (the handler raises; a test never waits on a timer for it)."""
    os.kill(os.getpid(), sig)
    for _ in range(1000):
        time.sleep(0)


def test_sigterm_raises_terminated_and_the_handlers_come_back() -> None:
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(Terminated) as info, interrupts_as_keyboard() as received:
        _deliver(signal.SIGTERM)
    assert isinstance(info.value, KeyboardInterrupt)  # every Ctrl-C cleanup path catches it
    assert exit_code_for(info.value) == 143 and received.exit_code == 143
    assert signal.getsignal(signal.SIGTERM) is before


def test_an_inherited_ignored_sigint_still_interrupts() -> None:
    """A background job of a script starts with SIGINT ignored; inside the block Ctrl-C works,
    and the inherited disposition is put back after it."""
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with pytest.raises(KeyboardInterrupt) as info, interrupts_as_keyboard() as received:
            _deliver(signal.SIGINT)
        assert not isinstance(info.value, Terminated)
        assert exit_code_for(info.value) == 130 and received.exit_code == 130
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, previous)


def test_off_the_main_thread_it_changes_nothing() -> None:
    seen: list[object] = []

    def body() -> None:
        with interrupts_as_keyboard() as received:
            seen.append(signal.getsignal(signal.SIGTERM))
            seen.append(received.exit_code)

    before = signal.getsignal(signal.SIGTERM)
    t = threading.Thread(target=body)
    t.start()
    t.join()
    assert seen == [before, None]


def test_the_long_commands_are_marked() -> None:
    long = {c.name for c in COMMANDS if c.long}
    assert {"train", "compare", "deploy", "demo"} <= long
    assert "arm" not in long and "envs" not in long


@pytest.mark.realtime
def test_sigterm_stops_a_mock_deployment_cleanly(
    tmp_path: Path, spawn: Callable[..., subprocess.Popen[str]]
) -> None:
    """A deployment stopped by SIGTERM (a container stop) keeps its log, reports itself stopped
    early, parks the arm and exits 143, exactly as Ctrl-C does (130). The shipped reach-ppo, in
    short episodes: the signal arrives once the first has ended, whatever the machine's load."""
    log = tmp_path / "mock.npz"
    proc = spawn(
        [sys.executable, "-m", "sim2real", "deploy", "reach-ppo", "--backend", "mock",
         "--episodes", "1000", "--steps", "10", "--log", str(log), "--json", "-v",
         "--watchdog-s", str(scaled(10)), "--start-timeout", str(scaled(60)),
         "--camera-fps", "20"],
        # judged: the signal, not the timing
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stderr is not None
    lines = []
    for line in proc.stderr:  # wait until an episode has finished: the loop is running
        lines.append(line)
        if "episode 0:" in line:
            break
    assert any("episode 0:" in ln for ln in lines), "".join(lines[-20:])
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=scaled(120))
    assert proc.returncode == 143, err[-2000:]
    assert "deploy: interrupted (SIGTERM)" in err
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["stopped_early"] is not None and 1 <= summary["episodes"] < 1000
    assert log.is_file()
