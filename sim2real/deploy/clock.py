"""The control period's clock: sleep to the next period, measure what each one really took.

A period starts on a fixed grid (``start + k / rate``). A late period is counted and logged,
never an error, and the next one starts at once: catching up would burst commands at the arm.
"""

from __future__ import annotations

import logging
import math
import time

# the runtime's messages keep the deploy loop's logger name: log filters (and tests) select it
log = logging.getLogger("sim2real.deploy.loop")


def sleep_until(deadline: float) -> None:
    """Sleep most of the way, then spin the last ~1 ms: time.sleep alone jitters by ~1 ms."""
    remaining = deadline - time.perf_counter()
    if remaining > 0.0015:
        time.sleep(remaining - 0.001)
    while time.perf_counter() < deadline:
        pass


class PeriodClock:
    """Paces one control loop and keeps its timing: every period's length (start to start),
    how late each wake-up came after its deadline, and the overruns."""

    def __init__(self, rate_hz: float, overrun_warn_fraction: float, sleeps: bool = True) -> None:
        self.period_s = 1.0 / rate_hz
        # False: the world waits for the loop (a lockstep simulator), so a period starts as
        # soon as the last one's work is done: periods are still measured (an overrun is work
        # longer than a period), no wake-up is late
        self.sleeps = sleeps
        self.overrun_warn_fraction = overrun_warn_fraction
        self.periods_s: list[float] = []
        # per period after a sleep: the wake-up after the deadline (the kernel's wake-up plus
        # the wait for the GIL), the part of the jitter the period's own work does not explain
        self.wake_late_s: list[float] = []
        self.overruns = 0
        self._next_t = self._last_start = time.perf_counter()
        self._slept = False  # the last period ended in a sleep to _next_t
        self._ticked = False  # a period has started since start(): the next tick measures it

    def start(self) -> None:
        """An episode's first period starts now; nothing before it is measured."""
        self._next_t = self._last_start = time.perf_counter()
        self._slept = self._ticked = False

    def restart(self) -> None:
        """The current period starts again now (after a pause: a pause is not a late period)."""
        self._next_t = self._last_start = time.perf_counter()
        self._slept = False

    def tick(self) -> tuple[float, float]:
        """A period starts: record the one before it. Returns (its length, the wake-up's
        lateness), NaN where there is none (an episode's first period, a period not slept to)."""
        start = time.perf_counter()
        late = start - self._next_t if self._slept else math.nan
        if self._slept:
            self.wake_late_s.append(late)
        period = math.nan
        if self._ticked:
            period = start - self._last_start
            self.periods_s.append(period)
            if period > self.period_s * (1 + self.overrun_warn_fraction):
                self.overruns += 1
                log.warning(
                    "overrun: period %.1f ms (nominal %.1f ms)", period * 1e3, self.period_s * 1e3
                )
        self._last_start, self._ticked = start, True
        return period, late

    def sleep(self) -> None:
        """Sleep to the next period's start on the grid; a late period starts the next at once."""
        if not self.sleeps:
            self._next_t, self._slept = time.perf_counter(), False
            return
        self._next_t += self.period_s
        self._slept = self._next_t - time.perf_counter() > 0
        if self._slept:
            sleep_until(self._next_t)
        else:
            self._next_t = time.perf_counter()  # do not try to catch up: it bursts
