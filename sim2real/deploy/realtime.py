"""Real-time scheduling for the control loop's thread, where the OS allows it.

A control loop that wakes late jitters, whatever its own code costs. On Linux a thread under
``SCHED_FIFO`` runs as soon as it wakes, ahead of every normal process (a training run on the
other core, the mock arm's process), as ros2_control's controller manager does. It needs root
or an rtprio limit (``ulimit -r``, ``/etc/security/limits.conf``); without them the loop runs at
normal priority and says so once. A process started under ``nice`` (a test run, a batch job)
asked for less, not more: it stays at normal priority.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from collections.abc import Iterator, Sequence

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
