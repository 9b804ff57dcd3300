"""Live view: a running deploy's periods streamed to Rerun without costing the loop its period.

The drawing runs in a child process (``python -m sim2real.view.live_child``, a
``deploy.child.ChildProcess``): drawing in Python (the series, the safety filter's replay,
Rerun's Arrow conversion) holds the interpreter's lock, and on a thread of the control process
the loop, awake on time, would wait for it. The control thread's ``LiveProcess.log_period(row,
frames)`` only copies the row onto the channel (``post``, which never waits) and the camera pair
into a ring of shared-memory slots under the sequence lock; the child copies a pair out and
skips one the parent overwrote meanwhile. The child counts what it drew in shared memory, so
the parent knows the backlog without asking: a child that lags keeps only the newest periods
(``queue_periods``), a stalled one makes the parent drop periods rather than queue them, and
the counts say what was skipped (``dropped``). A child that dies (a viewer gone, a drawing
error) is logged once and bypassed: the arm never stops for its viewer.

    live = LiveProcess(LiveJob(spec, objects=("target",), target="spawn", rate_hz=20.0))
    with live:                       # starts the child; closing draws what is queued, flushes
        ...  # in the loop, after the period's row:  live.log_period(last_row(log.rows), frames)
"""

from __future__ import annotations

import importlib.util
import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from hardware.spec import ArmSpec
from sim2real.deploy import child
from sim2real.errors import ConfigError, Sim2RealError, UnknownNameError

log = logging.getLogger(__name__)

CHILD_MODULE = "sim2real.view.live_child"
_SLOT_FIELDS = 2  # per frame slot: [lock, period index]


class LiveViewError(Sim2RealError):
    """The live viewer's child failed to start (its one line), or it was used unstarted."""


@dataclass(frozen=True)
class LiveConfig:
    queue_periods: int = 8  # 0.4 s at 20 Hz: how far the child may lag; it skips the oldest
    stalled_periods: int = 64  # periods posted and not yet taken before the parent drops them
    frame_slots: int = 4  # camera pairs in shared memory (a 640x480 pair is 1.8 MB)
    frames_every: int = 1  # send the camera pair every N-th period (0: never)
    nice: int = 10  # the child yields its core to the loop
    start_timeout_s: float = 120.0  # the child imports Rerun (seconds on a loaded machine)
    close_timeout_s: float = 30.0  # how long ``close`` waits for the child to draw and flush

    def __post_init__(self) -> None:
        if not 1 <= self.queue_periods <= 100_000:
            raise ConfigError(f"queue_periods {self.queue_periods} not in [1, 100000]")
        if not self.queue_periods <= self.stalled_periods <= 1_000_000:
            raise ConfigError(
                f"stalled_periods {self.stalled_periods} not in "
                f"[queue_periods {self.queue_periods}, 1000000]"
            )
        if not 1 <= self.frame_slots <= 64:
            raise ConfigError(f"frame_slots {self.frame_slots} not in [1, 64]")
        if self.frames_every < 0:
            raise ConfigError(f"frames_every {self.frames_every} must be >= 0 (0: no frames)")
        if not 0 <= self.nice <= 19:
            raise ConfigError(f"nice {self.nice} not in [0, 19]")
        for name in ("start_timeout_s", "close_timeout_s"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} {getattr(self, name)} must be > 0")


@dataclass(frozen=True)
class LivePeriod:
    index: int  # periods since the view started
    row: Mapping[str, Any]  # one deploy log row (``LoopLog`` keys), copied
    frames_bgr: tuple[np.ndarray, np.ndarray] | None  # the cameras' pair as delivered (BGR)


def last_row(rows: Mapping[str, Sequence[Any]]) -> dict[str, Any]:
    """The newest row of a ``LoopLog``'s ``rows``: every key logged this period (a key the
    period did not log, such as ``grasped`` without the truth, is left out)."""
    n = len(rows.get("t_s", ()))
    return {k: v[-1] for k, v in rows.items() if n and len(v) == n}


@dataclass(frozen=True)
class LiveJob:
    """What the child draws and where (picklable: it is the child's job)."""

    spec: ArmSpec
    objects: tuple[str, ...]
    target: str = "spawn"  # a key of ``LIVE_TARGETS``
    where: str | None = None  # connect: the viewer's address; save: the file
    label: str = "live"
    rate_hz: float | None = None  # the loop's rate, for the overrun events (None: none)

    def __post_init__(self) -> None:
        object.__setattr__(self, "objects", tuple(self.objects))
        if self.target not in LIVE_TARGETS:
            raise UnknownNameError("live view target", self.target, LIVE_TARGETS)
        if self.target == "save" and not self.where:
            raise ConfigError("live view target 'save' needs a path (FILE.rrd)")
        if self.rate_hz is not None and not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ConfigError(f"rate_hz {self.rate_hz} must be > 0 (or None)")

    def sink(self) -> RerunSink:
        return RerunSink(self.spec, self.objects, self.target, self.where, self.label,
                         self.rate_hz)  # fmt: skip


class ChildCounts:
    """The child's counts in shared memory, written by the child only (one writer: no lock; the
    parent reads them for the backlog): periods drawn, periods it skipped to keep up, and pairs
    it skipped because the parent overwrote their slot meanwhile. ``name=None`` creates it."""

    KEYS = ("drawn", "skipped", "frames_skipped")

    def __init__(self, name: str | None = None) -> None:
        self._block = child.SharedBlock(8 * len(self.KEYS), name)
        self.values: np.ndarray = self._block.array(len(self.KEYS))
        if name is None:
            self.values[:] = 0.0

    @property
    def name(self) -> str:
        return self._block.name

    def add(self, key: str) -> None:
        self.values[self.KEYS.index(key)] += 1

    def read(self) -> dict[str, int]:
        return {k: int(v) for k, v in zip(self.KEYS, self.values, strict=True)}

    def done(self) -> int:
        """Periods the child took off the channel (drawn or skipped)."""
        return int(self.values[0] + self.values[1])

    def close(self) -> None:
        if not self._block.closed:
            del self.values  # the view goes before the buffer closes
            self._block.close()


class FrameRing:
    """Camera pairs in shared memory: ``slots`` slots, each under its own sequence lock with the
    index of the period it holds. The parent writes pairs into the slots in turn; the child
    copies a slot out and keeps it only if it still holds the period it asked for.
    ``name=None`` creates it (this process owns and unlinks it); a name attaches."""

    def __init__(self, shape: tuple[int, ...], slots: int, name: str | None = None) -> None:
        self.shape, self.slots = tuple(shape), slots
        header = 8 * _SLOT_FIELDS * slots
        self._block = child.SharedBlock(header + 2 * slots * int(np.prod(shape)), name)
        self.header: np.ndarray = self._block.array(_SLOT_FIELDS * slots)
        self.images: np.ndarray = self._block.array((slots, 2, *shape), np.uint8, header)
        if name is None:
            self.header[:] = 0.0
            self.header[1::_SLOT_FIELDS] = -1.0  # no period yet
        self._written = 0

    @property
    def name(self) -> str:
        return self._block.name

    def fits(self, pair: tuple[np.ndarray, np.ndarray]) -> bool:
        return all(im.shape == self.shape and im.dtype == np.uint8 for im in pair)

    def write(self, index: int, pair: tuple[np.ndarray, np.ndarray]) -> int:
        """Period ``index``'s pair into its slot (a memcpy); returns the slot."""
        slot = self._written % self.slots
        self._written += 1
        at = _SLOT_FIELDS * slot
        with child.seqlock(self.header, at):
            self.images[slot, 0] = pair[0]
            self.images[slot, 1] = pair[1]
            self.header[at + 1] = index
        return slot

    def read(self, index: int, slot: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Period ``index``'s pair, copied; None if the parent overwrote (or is writing) it."""
        at = _SLOT_FIELDS * slot

        def copy() -> tuple[float, np.ndarray, np.ndarray]:
            return (
                float(self.header[at + 1]),
                self.images[slot, 0].copy(),
                self.images[slot, 1].copy(),
            )

        got = child.read_consistent(self.header, copy, at=at, tries=3)
        if got is None or got[0] != index:
            return None
        return got[1], got[2]

    def close(self) -> None:
        if not self._block.closed:
            del self.header, self.images  # numpy views must go before the buffer closes
            self._block.close()


class LiveProcess:
    """The parent's side (``runner.LivePeriods``): ``log_period`` posts and returns; the child
    (``live_child``) draws. ``drawn``/``dropped`` count periods; ``failed`` is the child's death
    line once it died, after which the view is bypassed."""

    def __init__(self, job: LiveJob, config: LiveConfig | None = None) -> None:
        self.job, self.config = job, config or LiveConfig()
        self._counts = ChildCounts()
        self._child = child.ChildProcess(
            "live viewer", CHILD_MODULE, (job, self.config, self._counts.name),
            start_timeout_s=self.config.start_timeout_s,
            stop_timeout_s=self.config.close_timeout_s, nice=self.config.nice,
            error=LiveViewError,
        )  # fmt: skip
        self._ring: FrameRing | None = None
        self._index = 0  # periods offered
        self._posted = 0  # periods posted to the child
        self._parent_dropped = 0  # periods not posted: the child had stalled
        self._final: dict[str, int] | None = None  # the counts the child answered at stop
        self.failed: str | None = None
        self.closed = False

    @property
    def pid(self) -> int | None:
        return self._child.pid

    def start(self) -> LiveProcess:
        """Start the child and wait until its sink is up (a viewer spawned, connected, a file
        open): a sink that cannot start raises here, before the arm moves."""
        if importlib.util.find_spec("rerun") is None:  # named as the 'view' extra by the CLI
            raise ModuleNotFoundError("No module named 'rerun'", name="rerun")
        if self.closed:
            raise LiveViewError("the live view was closed; make a new one")
        if not self._child.running:
            try:
                self._child.start()
            except BaseException:
                self.close()  # the shared memory goes with it
                raise
        return self

    @property
    def drawn(self) -> int:
        return self._count("drawn")

    @property
    def dropped(self) -> int:
        """Periods offered and never drawn: skipped by a lagging child, or not posted to a
        stalled one."""
        return self._parent_dropped + self._count("skipped")

    @property
    def frames_skipped(self) -> int:
        return self._count("frames_skipped")

    def _count(self, key: str) -> int:
        return (self._final or self._counts.read())[key]

    def log_period(
        self, row: Mapping[str, Any], frames_bgr: tuple[np.ndarray, np.ndarray] | None = None
    ) -> bool:
        """Hand one period to the child (the control thread; never blocks). False: the period
        was not posted (a stalled or dead child)."""
        if self._child.pid is None:
            raise LiveViewError("the live view was not started (start() or a with block)")
        index = self._index
        self._index += 1
        if self.failed is not None or self.closed:
            return False
        died = self._child.death()
        if died is not None:
            self.failed = died
            log.warning("live view stopped drawing: %s", died)
            return False
        if self._posted - self._counts.done() >= self.config.stalled_periods:
            self._parent_dropped += 1
            return False
        slot = self._frames(index, frames_bgr)
        self._child.post("period", index, {k: _copy(v) for k, v in row.items()}, slot)
        self._posted += 1
        return True

    def _frames(self, index: int, pair: tuple[np.ndarray, np.ndarray] | None) -> int | None:
        """The pair into the ring (made at the first pair, its shape the run's); its slot."""
        every = self.config.frames_every
        if pair is None or not every or index % every:
            return None
        if self._ring is None:
            self._ring = FrameRing(pair[0].shape, self.config.frame_slots)
            self._child.post("frames", self._ring.name, self._ring.shape, self._ring.slots)
        if not self._ring.fits(pair):  # a camera does not change its size mid-run
            return None
        return self._ring.write(index, pair)

    def close(self) -> None:
        """The child draws what it was sent (up to ``close_timeout_s``), flushes and closes its
        sink and answers its counts; then it is gone (killed if it does not answer)."""
        if self.closed:
            return
        self.closed = True
        started = self._child.pid is not None
        died = self._child.death()
        answer = self._child.stop()
        if isinstance(answer, dict) or not started:
            self._final = answer or self._counts.read()
        else:  # dead or killed: what it had counted in shared memory
            self._final = self._counts.read()
            if self.failed is None:
                self.failed = died or "the live viewer did not answer its stop in time"
                log.warning("live view stopped drawing: %s", self.failed)
        self._counts.close()
        if self._ring is not None:
            self._ring.close()

    def __enter__(self) -> LiveProcess:
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
