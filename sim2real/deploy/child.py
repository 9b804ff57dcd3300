"""What the parent of a deploy child process (the mock arm, perception) says when it dies, and
the environment it starts the child in.

One place for the one-line error a child prints before it exits, and for the line the parent
raises from the child's exit status and the last line of its stderr.
"""

from __future__ import annotations

import contextlib
import os
import signal
from typing import IO

# numpy's BLAS (OpenBLAS here) and the OpenMP runtimes read these when they load
ONE_THREAD_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def child_env() -> dict[str, str]:
    """The environment for a child of the control loop (the mock arm, render and perception
    processes): this one, with single-threaded BLAS and OpenMP (why:
    ``realtime.single_threaded_blas``)."""
    return {**os.environ, **ONE_THREAD_ENV}


def one_line(exc: BaseException) -> str:
    """The child's last words: the exception's type and first line."""
    text = (str(exc).splitlines() or [""])[0]
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def death_line(what: str, rc: int | None, stderr: IO[bytes] | None) -> str | None:
    """``"the <what> died (<how>): <last stderr line>"``, or None while it runs (``rc`` None)."""
    if rc is None:
        return None
    how = f"killed by {signal.Signals(-rc).name}" if rc < 0 else f"exit {rc}"
    last = _last_words(stderr) if rc > 0 else ""  # a signal leaves no words of its own
    return f"the {what} died ({how})" + (f": {last}" if last else "")


def _last_words(stderr: IO[bytes] | None) -> str:
    if stderr is None:
        return ""
    with contextlib.suppress(OSError):
        stderr.seek(0, os.SEEK_END)
        stderr.seek(max(0, stderr.tell() - 4096))
        lines = stderr.read().decode(errors="replace").strip().splitlines()
        return lines[-1].strip() if lines else ""
    return ""
