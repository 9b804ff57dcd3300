"""What the benches share: one JSON line per figure, stamped so it can become a record, and a
busy second core.

Every figure a bench prints carries when, where and from what it was measured: ``date`` (UTC),
``machine`` (``platform.machine()`` and the CPU count), ``load`` (the 1-minute load average at
that moment), ``commit`` (``git rev-parse --short HEAD``, ``-dirty`` when tracked files differ
from it) and ``command`` (the bench's own argv). Figures keep printing to stdout; with
``--record AREA`` (or ``BENCH_RECORD=AREA``) they are also appended to
``bench/records/AREA.jsonl``, the files ``bench/pages.py`` renders into the docs' benchmark pages.
``AREA`` may also be a path to a ``.jsonl`` file.

The ``--record`` option is taken out of ``sys.argv`` when this module is imported, so a bench's
own argument parser never sees it; import this module before parsing arguments.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import functools
import json
import os
import platform
import shlex
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]
RECORDS_DIR = REPO / "bench" / "records"
RECORD_ENV = "BENCH_RECORD"


def _take_record_flag(argv: list[str]) -> str | None:
    """Remove ``--record AREA`` / ``--record=AREA`` from ``argv``; the value, if given."""
    for i, arg in enumerate(argv):
        if arg == "--record" and i + 1 < len(argv):
            value = argv[i + 1]
            del argv[i : i + 2]
            return value
        if arg.startswith("--record="):
            del argv[i]
            return arg.split("=", 1)[1]
    return None


_RECORD_FLAG = _take_record_flag(sys.argv)
# The command that reproduces a figure: the bench as it was run, without --record.
_COMMAND = " ".join(shlex.quote(a) for a in ["python", *sys.argv])


def record_path(area: str | None = None) -> Path | None:
    """Where figures are appended: ``--record``, else ``$BENCH_RECORD``, else nowhere."""
    chosen = area or _RECORD_FLAG or os.environ.get(RECORD_ENV)
    if not chosen:
        return None
    if chosen.endswith(".jsonl") or os.sep in chosen:
        return Path(chosen)
    return RECORDS_DIR / f"{chosen}.jsonl"


@functools.lru_cache(maxsize=1)
def commit() -> str:
    """The checkout's short commit, ``-dirty`` when tracked files differ; ``unknown`` outside git."""
    try:
        head = subprocess.run(
            ["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"],
            capture_output=True, text=True, check=True,
        ).stdout.strip()  # fmt: skip
        # what a bench writes as it measures (its records; a shipped policy's file and card)
        # is not a change to the code it measures
        dirty = subprocess.run(
            ["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no", "--",
             ".", ":!bench/records", ":!sim2real/policies"],
            capture_output=True, text=True, check=True,
        ).stdout.strip()  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return f"{head}-dirty" if dirty else head


def machine() -> str:
    """``x86_64 2 cpu``: the form the policy cards use."""
    return f"{platform.machine()} {os.cpu_count()} cpu"


def stamp() -> dict[str, Any]:
    """When, where and from what a figure is measured, as of now."""
    try:
        load: float | None = round(os.getloadavg()[0], 2)
    except OSError:  # not available on this platform
        load = None
    return {
        "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "machine": machine(),
        "load": load,
        "commit": commit(),
        "command": _COMMAND,
    }


def emit_row(row: dict[str, Any], record: str | None = None) -> dict[str, Any]:
    """Print one figure (a dict with at least ``metric``) stamped; append it to the records file
    when recording. Returns the stamped row. The bench's own keys win over the stamp's."""
    stamped = {**row, **{k: v for k, v in stamp().items() if k not in row}}
    line = json.dumps(stamped)
    print(line, flush=True)
    path = record_path(record)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("a") as f:
            f.write(line + "\n")
    return stamped


def emit(metric: str, value: object, unit: str = "", **extra: object) -> dict[str, Any]:
    """One figure: ``metric``, ``value``, ``unit`` and whatever else the bench knows about it."""
    return emit_row({"metric": metric, "value": value, "unit": unit, **extra})


@contextlib.contextmanager
def busy_core() -> Iterator[None]:
    """Another process keeping one core busy (a training run beside the arm)."""
    proc = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        yield
    finally:
        proc.kill()
        proc.wait()
