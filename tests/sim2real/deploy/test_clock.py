"""The control period's clock: a grid of period starts, late periods counted, never caught up."""

from __future__ import annotations

import math
import time

import pytest

from sim2real.deploy.clock import PeriodClock, sleep_until


def test_an_episodes_first_period_is_not_measured_and_the_next_ones_are() -> None:
    clock = PeriodClock(rate_hz=100.0, overrun_warn_fraction=0.2)
    clock.start()
    period_s, late_s = clock.tick()
    assert math.isnan(period_s) and math.isnan(late_s)  # nothing before it, nothing slept to
    for _ in range(3):
        clock.sleep()
        period_s, late_s = clock.tick()
        assert period_s >= 0.0095 and late_s >= 0.0
    assert len(clock.periods_s) == 3 and len(clock.wake_late_s) == 3
    clock.start()  # a new episode: its first period is not measured either
    assert math.isnan(clock.tick()[0]) and len(clock.periods_s) == 3


def test_a_late_period_is_counted_once_and_the_next_starts_at_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clock = PeriodClock(rate_hz=50.0, overrun_warn_fraction=0.2)
    clock.start()
    clock.tick()
    time.sleep(3 * clock.period_s)  # the period's work ran long
    clock.sleep()  # nothing to sleep: the next period starts now, no burst to catch up
    period_s, late_s = clock.tick()
    assert period_s >= 3 * clock.period_s and math.isnan(late_s)
    assert clock.overruns == 1 and "overrun: period" in caplog.text
    t0 = time.perf_counter()
    clock.sleep()  # back on a grid that starts at the late period's end
    assert time.perf_counter() - t0 >= 0.9 * clock.period_s


def test_restart_makes_a_pause_no_late_period() -> None:
    clock = PeriodClock(rate_hz=50.0, overrun_warn_fraction=0.2)
    clock.start()
    clock.tick()
    time.sleep(5 * clock.period_s)  # paused by a person
    clock.restart()
    clock.sleep()
    period_s, _ = clock.tick()
    assert period_s < 4 * clock.period_s  # measured from the restart, not from before the pause


def test_sleep_until_never_wakes_early() -> None:
    deadline = time.perf_counter() + 0.005
    sleep_until(deadline)
    assert time.perf_counter() >= deadline
