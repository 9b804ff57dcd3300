"""The live viewer's child process (``python -m sim2real.view.live_child``): it builds the
``RerunSink`` from its job, then draws the periods ``live.LiveProcess`` posts, with their camera
pairs copied out of the shared ring. Between two drawings it takes everything waiting on the
channel; beyond ``queue_periods`` waiting it skips the oldest (a live view shows now). It counts
what it drew and skipped in shared memory for the parent; at stop it draws what is left, flushes
and closes the sink and answers its counts. A drawing that fails ends the child (its one line
is the parent's ``failed``), after flushing what it drew."""

from __future__ import annotations

import contextlib
from collections import deque
from typing import Any

from sim2real.deploy import child
from sim2real.view.live import (
    ChildCounts,
    FrameRing,
    LiveConfig,
    LiveJob,
    LivePeriod,
    RerunSink,
)


class _Drawing:
    """The child's state: the sink, the ring (once the parent made one), the counters."""

    def __init__(self, job: LiveJob, config: LiveConfig, counters_name: str) -> None:
        self.config = config
        self.counts = ChildCounts(counters_name)
        self.ring: FrameRing | None = None
        self.waiting: deque[tuple[int, dict[str, Any], int | None]] = deque()
        self.sink: RerunSink = job.sink()

    def take(self, op: str, args: tuple[Any, ...]) -> None:
        if op == "frames":
            name, shape, slots = args
            self.ring = FrameRing(tuple(shape), int(slots), name=name)
        elif op == "period":
            self.waiting.append(args)
            while len(self.waiting) > self.config.queue_periods:
                self.waiting.popleft()  # the oldest goes: the viewer shows the newest
                self.counts.add("skipped")
        else:
            raise KeyError(f"unknown op {op!r}; valid: ['frames', 'period']")

    def draw_one(self) -> None:
        index, row, slot = self.waiting.popleft()
        frames = None
        if slot is not None and self.ring is not None:
            frames = self.ring.read(index, slot)
            if frames is None:  # the parent wrote a newer pair there meanwhile
                self.counts.add("frames_skipped")
        self.sink.period(LivePeriod(index, row, frames))
        self.counts.add("drawn")

    def release(self) -> None:
        if self.ring is not None:
            self.ring.close()
        self.counts.close()


def _serve(channel: child.ChildChannel) -> dict[str, int]:
    job, config, counters_name = channel.job
    drawing = _Drawing(job, config, counters_name)
    channel.ready()
    try:
        while not channel.stopping:
            request = channel.receive(0.0 if drawing.waiting else None)
            if request is not None:
                drawing.take(request.op, request.args)  # everything waiting first
            elif drawing.waiting:
                drawing.draw_one()
        while drawing.waiting:  # the stop came after the last period: draw what is left
            drawing.draw_one()
    except BaseException:
        with contextlib.suppress(Exception):  # keep what was drawn (a saved file)
            drawing.sink.close()
        raise
    drawing.sink.close()
    answer = drawing.counts.read()
    drawing.release()
    return answer


def main() -> None:
    """The child's entry point (``child.run_child``)."""
    child.run_child(_serve)


if __name__ == "__main__":
    main()
