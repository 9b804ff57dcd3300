"""``LiveProcess``: the control thread posts a period and returns; a child process draws it with
the same ``RerunSink`` as ``sim2real view``, read back from the real file it saved. A stalled
child makes the parent drop periods (never block, never queue without bound); a child that dies
is logged once and bypassed; the child is gone after ``close`` whatever happened.

No assertion depends on a pace: a test that needs every period drawn sizes the queues to hold
the run, and waits are bounds that only turn a hang into a failure (``scaled``)."""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from timescale import scaled  # type: ignore[import-not-found]

from hardware.spec import load_spec
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.view.live import LiveConfig, LiveJob, LiveProcess, RerunSink, last_row

BOUND_S = scaled(60.0)  # only turns a hang into a failure


def _row(k: int) -> dict[str, object]:
    return {"t_s": 0.05 * k, "episode": 0, "step": k, "joints_rad": np.full(4, 0.01 * k)}


def _pair(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 255, (48, 64, 3), np.uint8), rng.integers(0, 255, (48, 64, 3), np.uint8)


def _job(out: Path) -> LiveJob:
    return LiveJob(load_spec(), ("target",), target="save", where=str(out), rate_hz=20.0)


def _alive(pid: int) -> bool:
    """Exists and is not a zombie."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    return "Z" not in next(ln for ln in status.splitlines() if ln.startswith("State:")).split()[1]


def _stop(pid: int) -> None:
    """SIGSTOP, and wait until it is stopped (before any period reaches it)."""
    os.kill(pid, signal.SIGSTOP)
    deadline = time.monotonic() + BOUND_S
    while time.monotonic() < deadline:
        status = Path(f"/proc/{pid}/status").read_text()
        if next(ln for ln in status.splitlines() if ln.startswith("State:")).split()[1] == "T":
            return
        time.sleep(0.01)
    raise AssertionError(f"the live viewer {pid} did not stop")


def _until_bypassed(live: LiveProcess, first: int) -> int:
    """Offer periods from ``first`` until the parent sees its child dead (bounded); the next."""
    deadline = time.monotonic() + BOUND_S
    k = first
    # until it says so: a refused period may also be the stall rule's (a child slow to die has
    # stopped taking periods), which is not the death this waits for
    while live.failed is None:
        assert time.monotonic() < deadline, "the parent never noticed its child's death"
        live.log_period(_row(k))
        k += 1
        time.sleep(0.01)
    return k


def _wait_gone(pid: int) -> bool:
    deadline = time.monotonic() + BOUND_S
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.02)
    return not _alive(pid)


def test_configs_and_targets_are_checked() -> None:
    with pytest.raises(ConfigError, match="queue_periods 0"):
        LiveConfig(queue_periods=0)
    with pytest.raises(ConfigError, match="stalled_periods 4"):
        LiveConfig(queue_periods=8, stalled_periods=4)
    with pytest.raises(UnknownNameError, match="live view target 'tv'"):
        LiveJob(load_spec(), ("target",), target="tv")
    with pytest.raises(ConfigError, match="needs a path"):
        LiveJob(load_spec(), ("target",), target="save")
    with pytest.raises(UnknownNameError, match="live view target 'tv'"):
        RerunSink(load_spec(), ("target",), target="tv")


def test_last_row_keeps_only_keys_logged_this_period() -> None:
    rows = {"t_s": [0.0, 0.05], "joints_rad": [np.zeros(4), np.ones(4)], "grasped": [1.0]}
    row = last_row(rows)
    assert set(row) == {"t_s", "joints_rad"} and row["t_s"] == 0.05


def test_the_child_draws_a_real_log_period_by_period(
    sim_log: Path, tmp_path: Path, rrd_counts: Callable[..., dict[str, int]]
) -> None:
    """Queues that hold the whole run: every period and every pair is drawn, whatever the pace."""
    log = dict(np.load(sim_log))
    n = len(log["joints_rad"])
    pairs = (n + 1) // 2
    assert pairs <= 64, "the ring must hold every pair for this test"
    out = tmp_path / "live.rrd"
    config = LiveConfig(queue_periods=n, stalled_periods=n, frames_every=2, frame_slots=pairs,
                        close_timeout_s=BOUND_S)  # fmt: skip
    rows: dict[str, list[object]] = {}
    pair = _pair()
    with LiveProcess(_job(out), config) as live:
        child = live.pid
        for k in range(n):  # as the loop would: append the period's row, hand the view its copy
            for key, values in log.items():
                rows.setdefault(key, []).append(values[k])
            assert live.log_period(last_row(rows), pair)
    assert child is not None and _wait_gone(child)
    assert (live.drawn, live.dropped, live.frames_skipped, live.failed) == (n, 0, 0, None)
    counts = rrd_counts(out)
    assert counts["/live/joints/shoulder/reading:Scalar"] == n
    assert counts["/live/joints/shoulder/sent:Scalar"] == n
    assert counts["/live/world/arm/reading:LineStrip3D"] == n
    assert counts["/live/world/truth/target:Position3D"] == n
    assert counts["/live/world/cameras/left/image:Blob"] == pairs


def test_a_stalled_child_drops_periods_and_never_blocks_the_caller(
    tmp_path: Path, rrd_counts: Callable[..., dict[str, int]]
) -> None:
    """The child is stopped (SIGSTOP) before the first period: it takes none, so the parent posts
    ``stalled_periods`` and drops the rest (a caller that waited would hang: pytest's timeout);
    resumed, it draws at most its ``queue_periods`` newest of them."""
    out = tmp_path / "live.rrd"
    config = LiveConfig(queue_periods=4, stalled_periods=16, frame_slots=2, close_timeout_s=BOUND_S)
    with LiveProcess(_job(out), config) as live:
        assert live.pid is not None
        _stop(live.pid)
        try:
            posted = [live.log_period(_row(k), _pair(k)) for k in range(200)]
        finally:
            os.kill(live.pid, signal.SIGCONT)
    assert posted == [True] * 16 + [False] * 184
    assert live.failed is None and live.drawn + live.dropped == 200
    assert 1 <= live.drawn <= 16 and live.dropped >= 184
    assert rrd_counts(out)["/live/joints/shoulder/reading:Scalar"] == live.drawn


def test_a_child_that_dies_mid_run_is_bypassed_with_one_line(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    live = LiveProcess(_job(tmp_path / "live.rrd")).start()
    pid = live.pid
    assert pid is not None
    with caplog.at_level(logging.WARNING, logger="sim2real.view.live"):
        assert live.log_period(_row(0), _pair())
        os.kill(pid, signal.SIGKILL)
        k = _until_bypassed(live, 1)
        results = [live.log_period(_row(j), _pair()) for j in range(k, k + 49)]
        live.close()
    assert results == [False] * 49
    assert live.failed == "the live viewer died (killed by SIGKILL)"
    lines = [r.getMessage() for r in caplog.records if r.name == "sim2real.view.live"]
    assert lines == ["live view stopped drawing: the live viewer died (killed by SIGKILL)"]


def test_a_drawing_error_ends_the_child_in_one_line_and_keeps_what_it_drew(
    tmp_path: Path, rrd_counts: Callable[..., dict[str, int]], caplog: pytest.LogCaptureFixture
) -> None:
    out = tmp_path / "live.rrd"
    live = LiveProcess(_job(out)).start()
    pid = live.pid
    assert pid is not None
    with caplog.at_level(logging.WARNING, logger="sim2real.view.live"):
        for k in range(3):
            assert live.log_period(_row(k))
        # drawn first: a child still busy with its first drawing when the later periods come
        # keeps only the newest queue_periods of them, and might skip the malformed one
        deadline = time.monotonic() + BOUND_S
        while live.drawn < 3:
            assert time.monotonic() < deadline, f"the child drew {live.drawn} of 3 periods"
            time.sleep(0.01)
        live.log_period({**_row(3), "t_s": "not a time"})  # a malformed row
        _until_bypassed(live, 4)  # (a zombie's threads may still be flushing the file)
        live.close()
    assert live.failed == (
        "the live viewer died (exit 3): ValueError: could not convert string to float: 'not a time'"
    )
    assert sum(r.name == "sim2real.view.live" for r in caplog.records) == 1
    assert live.drawn == 3
    assert rrd_counts(out)["/live/joints/shoulder/reading:Scalar"] == 3


def test_the_child_is_gone_after_an_error_and_after_a_hang(tmp_path: Path) -> None:
    with (
        pytest.raises(RuntimeError, match="the run failed"),
        LiveProcess(_job(tmp_path / "a.rrd")) as live,
    ):
        pid = live.pid
        live.log_period(_row(0))
        raise RuntimeError("the run failed")
    assert pid is not None and _wait_gone(pid)

    hung = LiveProcess(_job(tmp_path / "b.rrd"), LiveConfig(close_timeout_s=0.5)).start()
    pid = hung.pid
    assert pid is not None
    hung.log_period(_row(0))
    _stop(pid)  # it never answers its stop: killed
    hung.close()
    assert _wait_gone(pid)
    assert hung.failed is not None and "did not answer" in hung.failed


HOST = """
import sys, time
from hardware.spec import load_spec
from sim2real.view.live import LiveJob, LiveProcess
live = LiveProcess(LiveJob(load_spec(), ("target",), target="save", where=sys.argv[1])).start()
print(live.pid, flush=True)
time.sleep(600)
"""


def test_the_child_dies_with_its_host(tmp_path: Path) -> None:
    host = subprocess.Popen([sys.executable, "-c", HOST, str(tmp_path / "h.rrd")],
                            stdout=subprocess.PIPE, text=True)  # fmt: skip
    pid: int | None = None
    try:
        assert host.stdout is not None
        pid = int(host.stdout.readline())
        host.kill()  # none of its cleanup runs
        host.wait()
        assert _wait_gone(pid), "the live viewer outlived its host"
    finally:
        host.kill()
        host.wait()
        if pid is not None and _alive(pid):
            os.kill(pid, signal.SIGKILL)


def test_deploy_view_streams_a_live_run_through_the_child(
    tmp_path: Path, rrd_counts: Callable[..., dict[str, int]], capsys: pytest.CaptureFixture[str]
) -> None:
    """``sim2real deploy --view save:FILE``: the file holds what the child drew, one row a
    period drawn (the lockstep clock runs faster than a viewer: the summary counts the rest)."""
    from sim2real.cli.main import main

    rrd, log_path = tmp_path / "live.rrd", tmp_path / "run.npz"
    args = ["deploy", "reach-ppo", "--backend", "sim", "--episodes", "1", "--sim-clock",
            "lockstep", "--log", str(log_path), "--view", f"save:{rrd}", "--json"]  # fmt: skip
    assert main(args) == 0
    live: dict[str, Any] = json.loads(capsys.readouterr().out)["live_view"]
    periods = len(np.load(log_path)["joints_rad"])
    assert live["failed"] is None and live["drawn"] >= 1
    assert live["drawn"] + live["dropped"] == periods
    counts = rrd_counts(rrd)
    for joint in load_spec().actuator_names:
        for series in ("command", "sent", "reading"):
            assert counts[f"/live/joints/{joint}/{series}:Scalar"] == live["drawn"]
    assert counts["/live/world/arm/reading:LineStrip3D"] == live["drawn"]
    assert counts["/live/world/truth/target:Position3D"] == live["drawn"]
