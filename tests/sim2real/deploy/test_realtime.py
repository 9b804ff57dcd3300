"""The control loop's real-time priority: taken where the OS allows it, given back after, refused
with one warning line, and never taken by a process started under ``nice``.

Each case runs in a fresh process with the scheduling it needs (privileges, niceness), so the
test process's own scheduling is never changed.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

_PROBE = """
import json, logging, os, sys
if sys.argv[1:] == ["deny"]:  # the OS refuses, as it does without root or an rtprio limit
    def refuse(*args):
        raise PermissionError(1, "Operation not permitted")
    os.sched_setscheduler = refuse
logging.basicConfig(level=logging.WARNING, format="%(message)s")
import threading
from sim2real.deploy.realtime import control_thread_priority
stop = threading.Event()
reader = threading.Thread(target=stop.wait)  # a helper the loop waits on (a serial reader)
reader.start()
with control_thread_priority(helpers=[reader]) as got:
    inside = os.sched_getscheduler(0)
    helper_inside = os.sched_getscheduler(reader.native_id)
after = os.sched_getscheduler(0)
helper_after = os.sched_getscheduler(reader.native_id)
stop.set()
reader.join()
print(json.dumps({"got": got, "inside": inside, "after": after, "fifo": os.SCHED_FIFO,
                  "helper_inside": helper_inside, "helper_after": helper_after}))
"""


def _probe(*args: str, **popen: object) -> tuple[dict[str, int | bool], str]:
    res = subprocess.run(
        [sys.executable, "-c", _PROBE, *args], capture_output=True, text=True, timeout=120,
        **popen,
    )  # type: ignore[call-overload]  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    return json.loads(res.stdout.strip().splitlines()[-1]), res.stderr


def _at_nice(value: int) -> None:
    os.setpriority(os.PRIO_PROCESS, 0, value)  # root may lower it again; anyone may raise it


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to leave a nice test run's priority")
def test_the_loop_thread_gets_fifo_where_allowed_and_gives_it_back() -> None:
    out, _ = _probe(preexec_fn=lambda: _at_nice(0))
    assert out["got"] is True
    assert out["inside"] == out["fifo"] and out["after"] != out["fifo"]
    assert out["helper_inside"] == out["fifo"] and out["helper_after"] != out["fifo"]


def test_a_niced_process_stays_at_normal_priority() -> None:
    out, err = _probe(preexec_fn=lambda: _at_nice(max(5, os.getpriority(os.PRIO_PROCESS, 0))))
    assert out["got"] is False and out["inside"] != out["fifo"]
    assert out["helper_inside"] != out["fifo"]
    assert err == ""  # asked for less: nothing to warn about


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to leave a nice test run's priority")
def test_a_refusal_warns_in_one_line_and_the_loop_runs_normally() -> None:
    out, err = _probe("deny", preexec_fn=lambda: _at_nice(0))
    assert out["got"] is False and out["inside"] != out["fifo"]
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "real-time scheduling refused" in lines[0], err
