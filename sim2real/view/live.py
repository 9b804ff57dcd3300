"""Live view: a running deploy's periods streamed to Rerun without costing the loop its period.

The control thread calls ``LiveView.log_period(row, frames)`` once a period, right after the
period's log row is written. That call only copies the row (and, every ``frames_every`` periods,
the frame pair) into a bounded queue and returns; a worker thread draws from the queue into a
sink (``RerunSink``: the same drawing as ``sim2real view``, so a live run and its saved log look
alike). A full queue drops its oldest period, never blocks: a slow viewer shows the newest
periods and counts what it skipped (``dropped``). A sink that fails is logged once and then
ignored: the arm never stops for its viewer.

    live = LiveView(RerunSink(spec, objects=("target",), target="spawn"))
    with live:                       # starts the worker; closing drains what is queued
        ...  # in the loop, after the period's row:  live.log_period(last_row(log.rows), frames)
"""

from __future__ import annotations

import contextlib
import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol

import numpy as np

from hardware.spec import ArmSpec
from sim2real.errors import ConfigError, UnknownNameError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LiveConfig:
    queue_periods: int = 64  # ~3 s at 20 Hz: what a stalled viewer may lag before drops
    frames_every: int = 1  # send the camera pair every N-th period (0: never)
    close_timeout_s: float = 5.0  # how long ``close`` waits for the worker to drain

    def __post_init__(self) -> None:
        if not 1 <= self.queue_periods <= 100_000:
            raise ConfigError(f"queue_periods {self.queue_periods} not in [1, 100000]")
        if self.frames_every < 0:
            raise ConfigError(f"frames_every {self.frames_every} must be >= 0 (0: no frames)")
        if not self.close_timeout_s > 0:
            raise ConfigError(f"close_timeout_s {self.close_timeout_s} must be > 0")


@dataclass(frozen=True)
class LivePeriod:
    index: int  # periods since the view started
    row: Mapping[str, Any]  # one deploy log row (``LoopLog`` keys), copied
    frames_bgr: tuple[np.ndarray, np.ndarray] | None  # the cameras' pair as delivered (BGR)


class PeriodSink(Protocol):
    """Where the worker puts periods; runs on the worker thread only."""

    def period(self, item: LivePeriod) -> None: ...

    def close(self) -> None: ...


def last_row(rows: Mapping[str, Sequence[Any]]) -> dict[str, Any]:
    """The newest row of a ``LoopLog``'s ``rows``: every key logged this period (a key the
    period did not log, such as ``grasped`` without the truth, is left out)."""
    n = len(rows.get("t_s", ()))
    return {k: v[-1] for k, v in rows.items() if n and len(v) == n}


_STOP = object()


class LiveView:
    """A bounded queue and a worker thread between the control loop and a sink."""

    def __init__(self, sink: PeriodSink, config: LiveConfig | None = None) -> None:
        self.sink, self.config = sink, config or LiveConfig()
        self._queue: queue.Queue[Any] = queue.Queue(self.config.queue_periods)
        self._thread: threading.Thread | None = None
        self._index = 0
        self.dropped = 0  # periods dropped because the queue was full
        self.drawn = 0  # periods the sink took
        self.failed: str | None = None  # the sink's first error, after which it is bypassed

    def start(self) -> LiveView:
        if self._thread is None:
            self._thread = threading.Thread(target=self._work, name="live-view", daemon=True)
            self._thread.start()
        return self

    def log_period(
        self, row: Mapping[str, Any], frames_bgr: tuple[np.ndarray, np.ndarray] | None = None
    ) -> bool:
        """Queue one period (the control thread; never blocks). False: a period was dropped."""
        every = self.config.frames_every
        pair = None
        if frames_bgr is not None and every and self._index % every == 0:
            pair = (frames_bgr[0].copy(), frames_bgr[1].copy())  # the source reuses its buffers
        item = LivePeriod(self._index, {k: _copy(v) for k, v in row.items()}, pair)
        self._index += 1
        try:
            self._queue.put_nowait(item)
            return True
        except queue.Full:
            pass
        with contextlib.suppress(queue.Empty):  # the oldest goes: the viewer shows the newest
            self._queue.get_nowait()
        self.dropped += 1
        try:
            self._queue.put_nowait(item)
        except queue.Full:  # the worker is gone and another caller filled it: drop this one
            self.dropped += 1
        return False

    def _work(self) -> None:
        while True:
            item = self._queue.get()
            if item is _STOP:
                break
            if self.failed is not None:
                continue
            try:
                self.sink.period(item)
                self.drawn += 1
            except Exception as exc:  # the viewer went away: the deploy goes on without it
                self.failed = f"{type(exc).__name__}: {exc}"
                log.warning("live view stopped drawing: %s", self.failed)

    def close(self) -> None:
        """Drain what is queued (up to ``close_timeout_s``), stop the worker, close the sink."""
        thread, self._thread = self._thread, None
        if thread is not None:
            deadline = time.monotonic() + self.config.close_timeout_s
            while True:
                try:
                    self._queue.put(_STOP, timeout=0.05)
                    break
                except queue.Full:
                    if time.monotonic() > deadline or not thread.is_alive():
                        break
            thread.join(max(0.0, deadline - time.monotonic()))
        try:
            self.sink.close()
        except Exception as exc:
            log.warning("live view: closing the sink failed: %s", exc)

    def __enter__(self) -> LiveView:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def _copy(value: Any) -> Any:
    return value.copy() if isinstance(value, np.ndarray) else value


# ---- the Rerun sink -----------------------------------------------------------------------------
def _spawn(rec: Any, where: str | None) -> None:
    import rerun as rr

    rr.spawn(recording=rec)


def _connect(rec: Any, where: str | None) -> None:
    import rerun as rr

    rr.connect_tcp(where, recording=rec)  # a viewer already running (``rerun``), default port


def _save(rec: Any, where: str | None) -> None:
    import rerun as rr

    if not where:
        raise ConfigError("live view target 'save' needs a path (FILE.rrd)")
    rr.save(Path(where), recording=rec)


# where a live recording goes: a viewer started here, one already running, or a file
LIVE_TARGETS: dict[str, Callable[[Any, str | None], None]] = {
    "spawn": _spawn,
    "connect": _connect,
    "save": _save,
}


class RerunSink:
    """Draws live periods as ``sim2real view`` draws a log: the same entities under
    ``/<label>``, plus overruns and the safety filter's rules replayed as they happen."""

    def __init__(
        self,
        spec: ArmSpec,
        objects: Sequence[str],
        target: str = "spawn",
        where: str | None = None,
        label: str = "live",
        rate_hz: float | None = None,
        cameras: Any = None,
    ) -> None:
        import rerun as rr

        from hardware.safety import SafetyFilter
        from sim2real.view.draw import RunDrawer
        from sim2real.view.record import APPLICATION_ID, blueprint

        if target not in LIVE_TARGETS:
            raise UnknownNameError("live view target", target, LIVE_TARGETS)
        self.rec = rr.new_recording(APPLICATION_ID)
        self.spec, self.objects = spec, tuple(objects)
        self.drawer = RunDrawer(self.rec, label, spec, self.objects, cameras)
        self.nominal_s = 1.0 / rate_hz if rate_hz else math.nan
        self._filter = SafetyFilter(spec)
        self._prev_sent: np.ndarray | None = None
        self._t0: float | None = None
        LIVE_TARGETS[target](self.rec, where)
        rr.send_blueprint(blueprint([label], cameras is not None), recording=self.rec)
        self.drawer.static({"kind": "live deploy", "label": label})

    def period(self, item: LivePeriod) -> None:
        from sim2real.view.draw import series

        row = item.row
        t = float(row.get("t_s", item.index))
        self._t0 = t if self._t0 is None else self._t0
        self.drawer.set_time(item.index, t - self._t0)
        self.drawer.scene(row)
        columns = {k: np.asarray([v], dtype=float) for k, v in row.items() if _numeric(v)}
        values = series(columns, self.spec.actuator_names, self.objects)
        self.drawer.scalars({k: float(v[0]) for k, v in values.items()})
        for name in self._events(row):
            self.drawer.scalars({f"events/{name}": 1.0})
            self.drawer.event(f"period {item.index}: {name.replace('safety/', 'safety: ')}")
        if item.frames_bgr is not None:
            left, right = item.frames_bgr
            self.drawer.frames((left[:, :, ::-1], right[:, :, ::-1]), row)

    def _events(self, row: Mapping[str, Any]) -> list[str]:
        out = []
        period = float(row.get("period_s", math.nan))
        if math.isfinite(period) and math.isfinite(self.nominal_s):
            from sim2real.view.signals import OVERRUN_FRACTION

            if period > self.nominal_s * (1 + OVERRUN_FRACTION):
                out.append("overrun")
        targets, sent = row.get("targets_rad"), row.get("sent_rad")
        if targets is not None and sent is not None:
            prev = self._prev_sent if row.get("step", 1) else None
            prev = np.asarray(row.get("joints_rad"), dtype=float) if prev is None else prev
            if prev.shape == (self.spec.n_actuators,) and np.all(np.isfinite(prev)):
                before = dict(vars(self._filter.stats))
                try:
                    self._filter.filter(np.asarray(targets, dtype=float), prev)
                    out += [f"safety/{k}" for k, v in vars(self._filter.stats).items()
                            if k != "commands" and v > before[k]]  # fmt: skip
                except Exception:  # a malformed row: no safety verdict for it
                    pass
            self._prev_sent = np.asarray(sent, dtype=float)
        return out

    def close(self) -> None:
        import rerun as rr

        self.rec.flush(blocking=True)
        rr.disconnect(recording=self.rec)


def _numeric(value: Any) -> bool:
    if value is None:
        return False
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True
