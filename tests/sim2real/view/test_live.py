"""``LiveView``: the control thread queues a period and returns; a worker drains the queue into
a sink. A slow sink drops the oldest periods and never blocks the caller; a failing one is
bypassed; ``RerunSink`` draws what ``sim2real view`` draws, read back from a real file."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from hardware.spec import load_spec
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.view.live import LiveConfig, LivePeriod, LiveView, RerunSink, last_row


class SlowSink:
    """A viewer that takes ``delay_s`` per period (a remote viewer on a slow link)."""

    def __init__(self, delay_s: float) -> None:
        self.delay_s = delay_s
        self.seen: list[int] = []
        self.threads: set[str] = set()
        self.closed = False

    def period(self, item: LivePeriod) -> None:
        self.threads.add(threading.current_thread().name)
        time.sleep(self.delay_s)
        self.seen.append(item.index)

    def close(self) -> None:
        self.closed = True


def _row(k: int) -> dict[str, object]:
    return {"t_s": 0.05 * k, "episode": 0, "step": k, "joints_rad": np.full(4, 0.01 * k)}


class StuckSink(SlowSink):
    """A viewer that draws nothing until ``release`` is set (a hung viewer)."""

    def __init__(self) -> None:
        super().__init__(0.0)
        self.release = threading.Event()

    def period(self, item: LivePeriod) -> None:
        self.release.wait()
        super().period(item)


def test_a_stuck_sink_never_blocks_the_caller_and_the_newest_periods_win() -> None:
    """No timing: the sink cannot draw a single period until all 100 were offered, so a caller
    that waited for it would never get there (pytest's timeout would fail the test)."""
    sink = StuckSink()
    with LiveView(sink, LiveConfig(queue_periods=4)) as live:
        for k in range(100):
            live.log_period(_row(k))
        dropped = live.dropped
        sink.release.set()
    # at most the queue's 4 and the one the worker holds are drawn: the rest were dropped
    assert dropped >= 100 - 5
    assert live.drawn + live.dropped == 100 and sink.seen == sorted(sink.seen)
    assert sink.seen[-1] == 99  # the drop is of the oldest: the viewer ends on the newest
    assert sink.threads == {"live-view"} and sink.closed


def test_the_worker_drains_every_period_a_fast_enough_sink_can_take() -> None:
    sink = SlowSink(delay_s=0.0)
    with LiveView(sink, LiveConfig(queue_periods=8)) as live:
        for k in range(50):
            live.log_period(_row(k))
            time.sleep(0.001)
    assert live.dropped == 0 and sink.seen == list(range(50))


def test_a_sink_that_fails_is_bypassed_and_the_caller_goes_on() -> None:
    class Broken(SlowSink):
        def period(self, item: LivePeriod) -> None:
            raise ConnectionError("viewer closed")

    live = LiveView(Broken(0.0)).start()
    for k in range(10):
        live.log_period(_row(k))
    live.close()
    assert live.failed is not None and "viewer closed" in live.failed and live.drawn == 0


def test_the_caller_copies_what_it_queues() -> None:
    """The loop reuses its buffers (and a camera its frame): the queued period must not change."""
    got: list[LivePeriod] = []
    gate = threading.Event()

    class Gated(SlowSink):
        def period(self, item: LivePeriod) -> None:
            gate.wait(5.0)
            got.append(item)

    frames = (np.zeros((4, 6, 3), np.uint8), np.zeros((4, 6, 3), np.uint8))
    row = _row(1)
    joints = row["joints_rad"]
    assert isinstance(joints, np.ndarray)
    with LiveView(Gated(0.0)) as live:
        live.log_period(row, frames)
        joints[:] = 9.0
        frames[0][:] = 255
        gate.set()
    assert got[0].frames_bgr is not None and int(got[0].frames_bgr[0].max()) == 0
    assert float(np.max(got[0].row["joints_rad"])) < 1.0


def test_last_row_keeps_only_keys_logged_this_period() -> None:
    rows = {"t_s": [0.0, 0.05], "joints_rad": [np.zeros(4), np.ones(4)], "grasped": [1.0]}
    row = last_row(rows)
    assert set(row) == {"t_s", "joints_rad"} and row["t_s"] == 0.05


def test_configs_and_targets_are_checked() -> None:
    with pytest.raises(ConfigError, match="queue_periods 0"):
        LiveConfig(queue_periods=0)
    with pytest.raises(UnknownNameError, match="live view target 'tv'"):
        RerunSink(load_spec(), ("target",), target="tv")


def test_the_rerun_sink_draws_a_real_log_period_by_period(
    sim_log: Path, tmp_path: Path, rrd_counts: Callable[..., dict[str, int]]
) -> None:
    log = dict(np.load(sim_log))
    n = len(log["joints_rad"])
    out = tmp_path / "live.rrd"
    sink = RerunSink(load_spec(), ("target",), target="save", where=str(out), rate_hz=20.0,
                     label="live")  # fmt: skip
    rng = np.random.default_rng(0)
    pair = (
        rng.integers(0, 255, (48, 64, 3), np.uint8),
        rng.integers(0, 255, (48, 64, 3), np.uint8),
    )
    rows: dict[str, list[object]] = {}
    with LiveView(sink, LiveConfig(queue_periods=n, frames_every=2)) as live:
        for k in range(n):  # as the loop would: append the period's row, hand the view its copy
            for key, values in log.items():
                rows.setdefault(key, []).append(values[k])
            assert live.log_period(last_row(rows), pair)
    assert live.dropped == 0 and live.drawn == n
    counts = rrd_counts(out)
    assert counts["/live/joints/shoulder/reading:Scalar"] == n
    assert counts["/live/joints/shoulder/sent:Scalar"] == n
    assert counts["/live/world/arm/reading:LineStrip3D"] == n
    assert counts["/live/world/truth/target:Position3D"] == n
    assert counts["/live/world/cameras/left/image:Blob"] == (n + 1) // 2


def test_deploy_view_streams_every_period_of_a_live_run(
    tmp_path: Path, rrd_counts: Callable[..., dict[str, int]]
) -> None:
    """``sim2real deploy --view save:FILE``: the live view of a sim deploy holds one row per
    period of its log (the drop never fires at this pace), drawn as ``sim2real view`` draws."""
    from sim2real.cli.main import main

    rrd, log_path = tmp_path / "live.rrd", tmp_path / "run.npz"
    args = ["deploy", "reach-ppo", "--backend", "sim", "--episodes", "1", "--sim-clock",
            "lockstep", "--log", str(log_path), "--view", f"save:{rrd}", "--json"]  # fmt: skip
    assert main(args) == 0
    periods = len(np.load(log_path)["joints_rad"])
    counts = rrd_counts(rrd)
    for joint in load_spec().actuator_names:
        for series in ("command", "sent", "reading"):
            assert counts[f"/live/joints/{joint}/{series}:Scalar"] == periods
    assert counts["/live/world/arm/reading:LineStrip3D"] == periods
    assert counts["/live/world/truth/target:Position3D"] == periods
