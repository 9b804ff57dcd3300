"""The runtime's one child-process base, on real processes: a small child module written here,
started with ``python -m`` as the mock arm, renderer, perception and learner are, its signals
read back from /proc, killed whatever happens.

Nothing here depends on a rate: the bounds only turn a hang into a failure.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from timescale import scaled  # type: ignore[import-not-found]

from hardware.errors import HardwareError
from sim2real.deploy.child import (
    ChildProcess,
    SharedBlock,
    read_consistent,
    seqlock,
)

from .children import assert_dies_with_its_host  # type: ignore[import-not-found]
from .conftest import kill_pid, pid_alive  # type: ignore[import-not-found]

BOUND_S = 60.0

_CHILD = """
import os, signal, sys, time
import numpy as np
from sim2real.deploy.child import SharedBlock, run_child, seqlock, serve_requests


def serve(channel):
    job = channel.job
    if job.get("fail_start"):
        raise RuntimeError("no such device: " + job["fail_start"])
    got = []
    block = SharedBlock(name=job["block"]) if job.get("block") else None

    def publish(n):
        view = block.array(9)
        for i in range(n):
            with seqlock(view):
                view[1:] = i
        del view

    channel.ready({"pid": os.getpid(), "pgid": os.getpgid(0)})
    serve_requests(channel, {
        "echo": lambda *a: a,
        "note": got.append,
        "notes": lambda: list(got),
        "sig": lambda: [int(signal.getsignal(s)) for s in (signal.SIGINT, signal.SIGTERM)],
        "nice": lambda: os.nice(0),
        "policy": lambda: os.sched_getscheduler(0),
        "publish": publish,
        "die": lambda: os._exit(7),
        "hang": lambda: time.sleep(3600),
    })
    if block is not None:
        block.close()
    return {"notes": len(got)}


if __name__ == "__main__":
    run_child(serve)
"""


@pytest.fixture
def module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    (tmp_path / "s2r_test_child.py").write_text(_CHILD)
    path = os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", ""), os.getcwd()])
    monkeypatch.setenv("PYTHONPATH", path)
    yield "s2r_test_child"


def _child(module: str, **job: object) -> ChildProcess:
    return ChildProcess("test child", module, dict(job), stop_timeout_s=2.0, nice=3)


def test_ready_requests_in_order_and_last_words(module: str) -> None:
    child = _child(module)
    try:
        info = child.start()
        assert info["pid"] == child.pid
        for i in range(50):
            child.post("note", i)  # never waits for the child
        assert child.call("echo", 1, "a") == (1, "a")
        assert child.call("notes") == list(range(50))  # posts arrive before a later call
        with pytest.raises(HardwareError, match=r"^nope failed in the test child: KeyError.*echo"):
            child.call("nope")
        assert child.stop() == {"notes": 50}
        assert not pid_alive(info["pid"])
    finally:
        child.stop()
        kill_pid(child.pid)


def test_the_child_sets_its_signals_group_and_priority_itself(module: str) -> None:
    """SIGINT and SIGTERM ignored however the parent started (an inherited ignored SIGINT:
    NOTES.md), its own process group (the terminal's Ctrl-C reaches the parent only), normal
    scheduling at the niceness asked for, below its parent's."""
    previous = signal.signal(signal.SIGINT, signal.SIG_DFL)
    child = _child(module)
    try:
        info = child.start()
        assert child.call("sig") == [int(signal.SIG_IGN)] * 2
        assert info["pgid"] == info["pid"] != os.getpgid(0)
        assert child.call("policy") == os.SCHED_OTHER
        assert child.call("nice") == os.nice(0) + 3
        os.kill(info["pid"], signal.SIGINT)
        os.kill(info["pid"], signal.SIGTERM)
        assert child.call("echo", "still here") == ("still here",)
    finally:
        signal.signal(signal.SIGINT, previous)
        child.stop()
        kill_pid(child.pid)


def test_a_child_that_cannot_start_is_one_line_and_leaves_nothing(module: str) -> None:
    child = _child(module, fail_start="/dev/ttyNONE")
    with pytest.raises(HardwareError) as info:
        child.start()
    assert str(info.value) == (
        "the test child died (exit 3): RuntimeError: no such device: /dev/ttyNONE"
    )
    assert child.pid is not None and not pid_alive(child.pid)


def test_a_death_is_one_line_naming_the_child_and_its_exit(module: str) -> None:
    child = _child(module)
    try:
        child.start()
        with pytest.raises(HardwareError, match=r"^the test child died \(exit 7\)$"):
            child.call("die")
        with pytest.raises(HardwareError, match=r"^the test child died \(exit 7\)$"):
            child.check_alive()
    finally:
        child.stop()


def test_the_context_exit_names_the_dead_child_over_the_error_it_caused(module: str) -> None:
    with pytest.raises(HardwareError) as info, _child(module) as child:
        assert child.pid is not None
        os.kill(child.pid, signal.SIGKILL)
        deadline = time.monotonic() + BOUND_S
        while child.death() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        raise OSError("the port went away")
    assert str(info.value) == "the test child died (killed by SIGKILL)"
    assert isinstance(info.value.__cause__, OSError)


def test_stop_kills_a_child_that_does_not_answer(module: str) -> None:
    child = _child(module)
    child.stop_timeout_s = 0.5  # it never answers: a longer wait only ends in the same kill
    child.start()
    pid = child.pid
    assert pid is not None
    child.post("hang")  # it ignores SIGTERM and never reads the stop request
    t0 = time.monotonic()
    child.stop()
    assert time.monotonic() - t0 < BOUND_S
    assert not pid_alive(pid)
    assert child.death() is None  # stopped, not died


_HOST = """
import sys
from sim2real.deploy.child import ChildProcess
child = ChildProcess("test child", "s2r_test_child", {})
child.start()
print(child.pid, flush=True)
sys.stdin.read()  # until killed
"""


def test_the_child_dies_when_its_parent_is_killed(module: str) -> None:
    assert_dies_with_its_host(_HOST, "test child")


def test_a_reader_never_takes_half_a_write_from_another_process(module: str) -> None:
    block = SharedBlock(8 * 9)
    view = block.array(9)
    view[:] = 0.0
    child = ChildProcess("test child", module, {"block": block.name}, stop_timeout_s=2.0)
    try:
        child.start()
        writes = 20_000
        child.post("publish", writes)
        seen, busy = set(), 0
        deadline = time.monotonic() + BOUND_S
        last = float(writes - 1)  # once it is seen the writer is done: nothing changes after
        again = False  # a round was posted again and has not begun yet
        while len(seen) < 200 and time.monotonic() < deadline:
            copy = read_consistent(view, view.copy, tries=1)
            if copy is None:
                busy += 1
                continue
            assert np.all(copy[1:] == copy[1]), copy  # one write's values, never two
            value = float(copy[1])
            again = again and value == last
            seen.add(value)
            if value == last and not again:  # the round is over
                if len(seen) >= 2:
                    break
                child.post("publish", writes)  # it ran before this loop read: once more
                again = True
        assert len(seen) >= 2
    finally:
        child.stop()
        kill_pid(child.pid)
        del view
        block.close()


def test_a_block_is_unlinked_by_its_owner_only() -> None:
    owner = SharedBlock(64)
    other = SharedBlock(name=owner.name)
    view = owner.array(8)
    with seqlock(view):
        assert read_consistent(view, view.copy) is None  # odd: a write is under way
        view[1] = 5.0
    assert read_consistent(view, view.copy)[1] == 5.0  # type: ignore[index]
    assert other.array(8)[1] == 5.0
    other.close()
    again = SharedBlock(name=owner.name)  # the attacher's close left it in place
    again.close()
    del view
    owner.close()
    with pytest.raises(FileNotFoundError):
        SharedBlock(name=owner.name)


def test_a_block_attached_in_its_owners_process_keeps_the_owners_registration() -> None:
    """A frame block read where it is written (a video, the live view): the attacher leaves the
    resource tracker's one entry to the owner, whose unlink removes it (before, the tracker
    said KeyError on its stderr, and would not have cleaned up after a crash)."""
    script = (
        "from sim2real.deploy.child import SharedBlock\n"
        "owner = SharedBlock(64)\n"
        "SharedBlock(name=owner.name).close()\n"
        "owner.close()\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=scaled(120))  # fmt: skip
    assert done.returncode == 0 and "KeyError" not in done.stderr, done.stderr
    assert "leaked" not in done.stderr, done.stderr
