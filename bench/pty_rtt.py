"""What a pseudo-terminal costs the mock arm's serial round trip, against a socketpair.

Both ends run at SCHED_FIFO where the OS allows it (as the deploy loop and the mock arm's process
do), with another process keeping a core busy. The bytes of a pty cross the kernel's tty layer,
which hands them on in a kernel worker thread at normal priority; a socketpair does not. On a
loaded machine the difference is the part of the mock's read/command time no priority of ours
can remove (a USB serial adapter's bytes take the same tty path).

    .venv/bin/python bench/pty_rtt.py --trips 300

JSON lines: ``pty_rtt_ms`` and ``socketpair_rtt_ms`` (p50, p99, max), with the 1-minute load.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import socket
import sys
import threading
import time
import tty

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import numpy as np
from support.load import busy_core, emit

FRAME = b"x" * 20  # about an s2r state reply


def _fifo(priority: int) -> bool:
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return True
    return False


def _normal() -> None:
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def round_trips(kind: str, trips: int) -> tuple[np.ndarray, bool]:
    """Round-trip times (ms) of FRAME through an echo thread over a pty or a socketpair."""
    if kind == "pty":
        host, device = os.openpty()
        tty.setraw(host)
        tty.setraw(device)
    else:
        a, b = socket.socketpair()
        host, device = a.detach(), b.detach()

    def echo() -> None:
        _fifo(40)  # the mock arm's priority
        while True:
            data = os.read(device, 64)
            if data == b"q":
                return
            os.write(device, data)

    thread = threading.Thread(target=echo, daemon=True)
    thread.start()
    realtime = _fifo(50)  # the loop's priority
    lat = []
    try:
        for _ in range(trips):
            t0 = time.perf_counter()
            os.write(host, FRAME)
            got = 0
            while got < len(FRAME):
                got += len(os.read(host, 64))
            lat.append(time.perf_counter() - t0)
            time.sleep(0.005)
        os.write(host, b"q")
    finally:
        _normal()
    thread.join(timeout=5.0)
    for fd in (host, device):
        os.close(fd)
    return np.asarray(lat) * 1e3, realtime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trips", type=int, default=300)
    args = parser.parse_args()
    machine = f"{platform.machine()} {os.cpu_count()} cpu"
    with busy_core():
        for kind in ("pty", "socketpair", "pty", "socketpair"):
            lat, realtime = round_trips(kind, args.trips)
            p50, p99, worst = (round(float(v), 3) for v in np.percentile(lat, [50, 99, 100]))
            emit(f"{kind}_rtt_ms", p99, "ms", p50=p50, max=worst, trips=args.trips,
                 realtime=realtime, load_1min=round(os.getloadavg()[0], 2), machine=machine)  # fmt: skip


if __name__ == "__main__":
    main()
