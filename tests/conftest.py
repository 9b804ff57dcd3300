"""Test-wide settings: headless rendering before anything imports MuJoCo; ``spawn`` for tests
that start processes; ``tests/`` importable, for ``timescale`` (the one wall-clock factor)."""

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

_TESTS = str(Path(__file__).resolve().parent)
if _TESTS not in sys.path:  # ``from timescale import scaled`` in any test
    sys.path.insert(0, _TESTS)

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
os.environ.setdefault("OMP_NUM_THREADS", "1")


def _child_defaults() -> None:
    """Runs in the child before exec: default SIGINT and SIGTERM whatever this process inherited
    (a background job of a script starts with SIGINT ignored), and a process group of its own so
    the test can kill the child with everything it started."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    os.setpgid(0, 0)


def _kill_group(proc: subprocess.Popen[Any]) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):  # the group is gone already
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


@pytest.fixture
def spawn() -> Iterator[Callable[..., subprocess.Popen[Any]]]:
    """``spawn(cmd, **popen_kwargs)``: a child with the signal dispositions the test relies on,
    killed with its whole process group when the test ends, whatever happened."""
    started: list[subprocess.Popen[Any]] = []

    def start(cmd: list[str], **kwargs: Any) -> subprocess.Popen[Any]:
        proc = subprocess.Popen(cmd, preexec_fn=_child_defaults, **kwargs)
        started.append(proc)
        return proc

    try:
        yield start
    finally:
        for proc in started:
            _kill_group(proc)
