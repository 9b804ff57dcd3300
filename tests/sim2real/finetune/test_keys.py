"""Human-in-the-loop keys through a real pseudo-terminal: bytes written to the master side arrive
on the slave tty that ``HumanKeys`` reads in cbreak mode, on its own thread.

No assertion depends on timing: each check waits on the keys' own condition (with a generous
bound that only turns a hang into a failure)."""

from __future__ import annotations

import json
import os
import pty
import select
import signal
import sys
import termios
import time
from collections.abc import Iterator
from datetime import datetime

import pytest

from sim2real.errors import ConfigError
from sim2real.finetune.keys import (
    ESTOP,
    FAILURE,
    PAUSE,
    RESET_DONE,
    RESUME,
    SUCCESS,
    HumanKeys,
)

HANG_S = 30.0  # a bound that only catches a hang


@pytest.fixture
def tty_pair() -> Iterator[tuple[int, int]]:
    master, slave = os.openpty()
    try:
        yield master, slave
    finally:
        os.close(master)
        os.close(slave)


def _wait_count(keys: HumanKeys, n: int) -> None:
    assert keys.wait_for(lambda: len(keys._interventions) >= n, None, 0.05, HANG_S), (
        keys.interventions
    )


def test_keys_arrive_through_a_pty_and_each_is_logged_with_both_times(
    tty_pair: tuple[int, int],
) -> None:
    master, slave = tty_pair
    estops: list[str] = []
    before = time.monotonic()
    with HumanKeys(slave, on_estop=estops.append) as keys:
        attrs = termios.tcgetattr(slave)
        assert not attrs[3] & termios.ICANON and not attrs[3] & termios.ECHO  # cbreak
        assert attrs[3] & termios.ISIG  # Ctrl-C still signals
        os.write(master, b" ")
        _wait_count(keys, 1)
        assert keys.paused
        os.write(master, b"p")  # the pause key again resumes
        _wait_count(keys, 2)
        assert not keys.paused
        os.write(master, b"s")
        _wait_count(keys, 3)
        assert keys.take_mark() is True and keys.take_mark() is None  # read once
        os.write(master, b"zF")  # an unknown key is ignored; upper case works
        _wait_count(keys, 4)
        assert keys.take_mark() is False
        os.write(master, b"e")
        _wait_count(keys, 5)
        assert keys.estopped and estops == ["e-stop key"]
    records = keys.interventions
    assert [r.action for r in records] == [PAUSE, RESUME, SUCCESS, FAILURE, ESTOP]
    assert [r.key for r in records] == [" ", "p", "s", "F", "e"]
    times = [r.monotonic_s for r in records]
    assert before <= times[0] and times == sorted(times) and times[-1] <= time.monotonic()
    for r in records:
        assert datetime.fromisoformat(r.utc).utcoffset().total_seconds() == 0  # type: ignore[union-attr]
        assert set(r.to_dict()) == {"action", "key", "monotonic_s", "utc"}


def test_the_estop_flag_is_up_while_the_arm_is_told(tty_pair: tuple[int, int]) -> None:
    """The arm's e-stop holds for a while before it returns: a learner refused by the latched
    arm meanwhile must already read ``estopped`` (and stop as the key says, not as an error)."""
    _, slave = tty_pair
    seen: list[bool] = []
    keys = HumanKeys(slave, on_estop=lambda reason: seen.append(keys.estopped))
    keys.press(b"e")  # the key thread's call, made here: no thread, no timing
    assert seen == [True] and keys.estopped


def test_waiting_for_a_reset_holds_the_arm_until_the_key(tty_pair: tuple[int, int]) -> None:
    master, slave = tty_pair
    holds: list[float] = []
    with HumanKeys(slave) as keys:
        assert not keys.wait_for_reset(lambda: holds.append(1.0), 0.01, timeout_s=0.05)
        assert holds, "the arm is held while waiting"
        os.write(master, b"\r")  # Enter (a tty in cbreak mode may pass CR or LF)
        assert keys.wait_for_reset(lambda: holds.append(1.0), 0.01, timeout_s=HANG_S)
        assert not keys.wait_for_reset(None, 0.01, timeout_s=0.0)  # consumed by the wait
        assert keys.interventions[-1].action == RESET_DONE
        os.write(master, b" ")
        _wait_count(keys, 2)
        os.write(master, b"e")  # an e-stop ends a pause wait with False
        assert not keys.wait_while_paused(None, 0.01)


def test_the_terminal_is_restored_when_the_block_raises(tty_pair: tuple[int, int]) -> None:
    _master, slave = tty_pair
    original = termios.tcgetattr(slave)
    with pytest.raises(RuntimeError, match="boom"), HumanKeys(slave):
        assert termios.tcgetattr(slave) != original
        raise RuntimeError("boom")
    assert termios.tcgetattr(slave) == original


def test_a_non_tty_is_refused_in_one_line() -> None:
    r, w = os.pipe()
    try:
        with pytest.raises(ConfigError, match=f"fd {r} is not a tty") as info:
            HumanKeys(r)
        assert "\n" not in str(info.value)
    finally:
        os.close(r)
        os.close(w)


CHILD = """
import json, os, signal, sys, termios
from sim2real.finetune.keys import HumanKeys

def on_term(signum, frame):
    raise KeyboardInterrupt  # as the long commands treat SIGTERM (sim2real.cli.signals)

signal.signal(signal.SIGTERM, on_term)
signal.signal(signal.SIGINT, signal.default_int_handler)
before = termios.tcgetattr(0)
try:
    with HumanKeys(0) as keys:
        print("READY", flush=True)
        keys.wait_for(lambda: bool(keys._interventions), None, 0.05)
        print("GOT", flush=True)
        keys.wait_for(lambda: False, None, 0.05)  # until the signal
except KeyboardInterrupt:
    pass
print(json.dumps({"restored": termios.tcgetattr(0) == before,
                  "actions": [r.action for r in keys.interventions]}), flush=True)
"""


def _read_until(fd: int, marker: bytes) -> bytes:
    out = b""
    deadline = time.monotonic() + HANG_S
    while marker not in out:
        assert time.monotonic() < deadline, out
        ready, _, _ = select.select([fd], [], [], 1.0)
        if ready:
            try:
                chunk = os.read(fd, 4096)
            except OSError:  # the child closed its side
                break
            if not chunk:
                break
            out += chunk
    return out


def test_a_process_on_its_own_terminal_restores_it_after_sigterm() -> None:
    """The keys run in a child whose controlling terminal is a pty (``pty.fork``); the parent
    types on the master, then sends SIGTERM; the child reports its terminal restored."""
    pid, master = pty.fork()
    if pid == 0:  # the child: never return into pytest
        try:
            os.execv(sys.executable, [sys.executable, "-c", CHILD])
        finally:
            os._exit(127)
    try:
        _read_until(master, b"READY")
        os.write(master, b"p")
        _read_until(master, b"GOT")
        os.kill(pid, signal.SIGTERM)
        out = _read_until(master, b"}")
        _, status = os.waitpid(pid, 0)
        pid = 0
        assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0, out
        report = json.loads(out[out.index(b"{") : out.rindex(b"}") + 1])
        assert report["restored"] is True
        assert report["actions"] == ["pause"]
    finally:
        if pid:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        os.close(master)
