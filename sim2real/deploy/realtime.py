"""Real-time scheduling for the control loop's thread, where the OS allows it, and what else
the loop must not wait for: the cyclic garbage collector (``QuietGC``) and a BLAS worker thread
(``single_threaded_blas``).

A control loop that wakes late jitters, whatever its own code costs. On Linux a thread under
``SCHED_FIFO`` runs as soon as it wakes, ahead of every normal process (a training run on the
other core, the mock arm's process), as ros2_control's controller manager does. It needs root
or an rtprio limit (``ulimit -r``, ``/etc/security/limits.conf``); without them the loop runs at
normal priority and says so once. A process started under ``nice`` (a test run, a batch job)
asked for less, not more: it stays at normal priority.
"""

from __future__ import annotations

import contextlib
import gc
import logging
import os
import threading
from collections.abc import Iterator, Sequence

from threadpoolctl import threadpool_limits

log = logging.getLogger(__name__)

CONTROL_PRIORITY = 50  # ros2_control's default for its real-time thread


def niced() -> bool:
    """Whoever started this process asked for a lower priority (``nice``, a test run): it is
    not escalated to real-time."""
    try:
        return os.getpriority(os.PRIO_PROCESS, 0) > 0
    except (OSError, AttributeError):
        return False


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """numpy's BLAS at one thread in this process inside the block, restored after.

    OpenBLAS splits a matrix-vector product (the numpy actor's 400 x 300 layers) with a worker
    thread at normal priority, and the caller waits at the product's end for it. A real-time
    loop whose worker was preempted by the learner or the renderer waited 20-110 ms there: late
    periods that no scheduler setting of the loop's thread reaches. Between products the idle
    worker spins on ``sched_yield`` (a third of a core on this 2-core machine). The loop's
    products are far too small to gain from a second thread."""
    with threadpool_limits(limits=1, user_api="blas"):
        yield


@contextlib.contextmanager
def control_thread_priority(
    enabled: bool = True,
    priority: int = CONTROL_PRIORITY,
    helpers: Sequence[threading.Thread] = (),
) -> Iterator[bool]:
    """The calling thread at ``SCHED_FIFO`` ``priority`` inside the block, restored after.
    Yields whether it got it. (Linux schedules threads: pid 0 is the calling thread, and
    threads started inside the block inherit the policy, so start others before it.)
    ``helpers``: threads on the loop's own path that it waits for (the serial link's reader,
    which wakes it when a reply arrives), raised with it: a loop at real-time priority that
    waits on a normal thread waits as long as the machine's load keeps that thread off the CPU."""
    setter = getattr(os, "sched_setscheduler", None)
    if not enabled or setter is None or niced():
        yield False
        return
    try:
        before = os.sched_getscheduler(0), os.sched_getparam(0)
        setter(0, os.SCHED_FIFO, os.sched_param(priority))
        raised = []
        for thread in helpers:
            tid = thread.native_id
            if tid is not None and thread.is_alive():
                raised.append((tid, os.sched_getscheduler(tid), os.sched_getparam(tid)))
                setter(tid, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        log.warning(
            "control loop at normal priority: real-time scheduling refused (%s); run as root "
            "or raise the rtprio limit (ulimit -r) to get it",
            exc.strerror or exc,
        )
        yield False
        return
    try:
        yield True
    finally:
        with contextlib.suppress(OSError):
            setter(0, before[0], before[1])
        for tid, policy, param in raised:
            with contextlib.suppress(OSError):  # a thread that ended meanwhile
                setter(tid, policy, param)


class QuietGC:
    """Python's cyclic garbage collector kept out of the control periods.

    A full (generation-2) collection walks every tracked object in the process, holding the GIL:
    in ``sim2real finetune``'s loop process (about 290,000 objects after its imports) one took
    100-130 ms, two periods lost whatever the loop's priority, and one falls due whenever enough
    long-lived objects (logs, episode records) have piled up. Inside the block automatic
    collection is off and what exists is frozen (``gc.freeze``: never scanned again);
    ``between()`` collects only what was allocated since (one episode's leftovers) and freezes
    the survivors. Call it where the loop is between periods. Garbage that refcounting frees
    (nearly all of a period's) goes as usual; a cycle among frozen objects waits until the block
    ends. Nested blocks defer to the outermost."""

    _depth = 0  # per process; the loop's own thread enters and leaves it

    def __enter__(self) -> QuietGC:
        cls = type(self)
        self._outer = cls._depth == 0
        if self._outer:
            self._was_enabled = gc.isenabled()
            gc.disable()
            try:
                gc.collect()
                gc.freeze()
            except BaseException:  # a Ctrl-C in the collection: nothing stays switched off
                self._restore()
                raise
        cls._depth += 1
        return self

    def between(self) -> None:
        """Collect what was allocated since the last call, outside any period."""
        if type(self)._depth == 0:
            raise RuntimeError("QuietGC.between() outside its block")
        gc.collect()
        gc.freeze()

    def __exit__(self, *exc: object) -> None:
        type(self)._depth -= 1
        if self._outer:
            self._restore()

    def _restore(self) -> None:
        """Unfreeze (a freeze made before the block is undone too) and re-enable."""
        gc.unfreeze()
        if self._was_enabled:
            gc.enable()
