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


_GC_PROBE = """
import gc, json, weakref
from sim2real.deploy.realtime import QuietGC

class Node:
    pass

def cycle():
    a, b = Node(), Node()
    a.other, b.other = b, a
    return weakref.ref(a)

before = gc.isenabled()
with QuietGC() as quiet:
    enabled_inside = gc.isenabled()
    frozen = gc.get_freeze_count()
    dead = cycle()  # garbage from birth: only the cyclic collector frees it
    churn = [[i] for i in range(50_000)]  # far past gen 0's threshold: no automatic collection
    del churn
    alive_in_period = dead() is not None
    with QuietGC():  # a nested block (deploy inside adapt) changes nothing
        pass
    enabled_after_nested = gc.isenabled()
    quiet.between()
    freed_between = dead() is None
    frozen_after_between = gc.get_freeze_count()
print(json.dumps({"before": before, "enabled_inside": enabled_inside, "frozen": frozen,
                  "alive_in_period": alive_in_period, "freed_between": freed_between,
                  "enabled_after_nested": enabled_after_nested,
                  "frozen_after_between": frozen_after_between,
                  "enabled_after": gc.isenabled(), "frozen_after": gc.get_freeze_count()}))
"""


def test_quiet_gc_collects_cycles_between_periods_and_never_inside_one() -> None:
    """In a fresh process: the test process's own collector is left alone."""
    res = subprocess.run(
        [sys.executable, "-c", _GC_PROBE], capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 0, res.stderr[-2000:]
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["before"] is True and out["enabled_inside"] is False
    assert out["frozen"] > 1000  # what existed (imports, numpy) is never scanned again
    assert out["alive_in_period"] is True  # 50,000 allocations and no collection
    assert out["enabled_after_nested"] is False  # the inner block did not re-enable it
    assert out["freed_between"] is True
    assert out["frozen_after_between"] >= out["frozen"]
    assert out["enabled_after"] is True and out["frozen_after"] == 0


_BLAS_PROBE = """
import json, os, sys
import numpy as np
from threadpoolctl import threadpool_info
from sim2real.deploy.realtime import single_threaded_blas

def blas_threads():
    return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]

np.ones((4, 4)) @ np.ones(4)  # BLAS loaded
before = blas_threads()
with single_threaded_blas():
    inside = blas_threads()
print(json.dumps({"before": before, "inside": inside, "after": blas_threads(),
                  "env": os.environ.get("OPENBLAS_NUM_THREADS")}))
"""


def _blas_probe(env: dict[str, str]) -> dict[str, object]:
    res = subprocess.run(
        [sys.executable, "-c", _BLAS_PROBE], capture_output=True, text=True, timeout=120, env=env
    )
    assert res.returncode == 0, res.stderr[-2000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(
    len(os.sched_getaffinity(0)) < 2, reason="OpenBLAS runs one thread on one CPU anyway"
)
def test_the_loop_runs_numpy_blas_on_one_thread_and_gives_the_pool_back() -> None:
    two = {**os.environ, "OPENBLAS_NUM_THREADS": "2", "OMP_NUM_THREADS": "2"}
    out = _blas_probe(two)
    assert out["before"] and max(out["before"]) > 1, out  # type: ignore[call-overload]
    assert out["before"] == out["after"], out
    assert out["inside"] == [1] * len(out["before"]), out  # type: ignore[arg-type]


def test_the_loops_children_start_with_single_threaded_blas(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from sim2real.deploy.child import child_env

    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")  # what the user's shell may say
    out = _blas_probe(child_env())
    assert out["env"] == "1" and out["before"], out  # numpy's BLAS was found
    assert out["before"] == [1] * len(out["before"]), out  # type: ignore[arg-type]
