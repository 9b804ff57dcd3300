"""The one factor for every wall-clock margin in the tests: ``SIM2REAL_TIME_SCALE``.

Tests that judge behaviour run on clocks a slow machine cannot change (the lockstep sim clock,
events, the emulator's own time). The few that must judge the wall-clock chain (a pty, child
processes, free-running cameras: the ``realtime`` marker) give a loaded machine wide margins,
and every such margin (a serial reply time-out, a watchdog, a wait for a process) is written as
``scaled(seconds)``. CI on a machine busier than a loaded 2-core one sets
``SIM2REAL_TIME_SCALE=3`` (say), and every margin grows with it; nothing else reads the variable.
The scale only ever widens a margin: a value below 1 is refused.
"""

from __future__ import annotations

import math
import os

ENV_VAR = "SIM2REAL_TIME_SCALE"


def _read() -> float:
    text = os.environ.get(ENV_VAR, "").strip()
    if not text:
        return 1.0
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{ENV_VAR}={text!r} is not a number (a factor >= 1)") from None
    if not (math.isfinite(value) and value >= 1.0):
        raise ValueError(f"{ENV_VAR}={text!r} must be a finite factor >= 1")
    return value


TIME_SCALE = _read()


def scaled(seconds: float) -> float:
    """A wall-clock margin (a time-out, a watchdog, a wait) widened by ``SIM2REAL_TIME_SCALE``."""
    return seconds * TIME_SCALE
