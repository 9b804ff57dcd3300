"""What the timing benches share: one JSON line per figure, and a busy second core."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
from collections.abc import Iterator


def emit(metric: str, value: object, unit: str = "", **extra: object) -> None:
    print(json.dumps({"metric": metric, "value": value, "unit": unit, **extra}), flush=True)


@contextlib.contextmanager
def busy_core() -> Iterator[None]:
    """Another process keeping one core busy (a training run beside the arm)."""
    proc = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        yield
    finally:
        proc.kill()
        proc.wait()
