"""The control period's clock: a grid of period starts, late periods counted, never caught up.

Load-proof: the grid is judged on a virtual clock; on the real one a stall (a loaded machine)
only makes a period late, and each assertion holds for a late period too, its bounds taken from
the clock before and after the calls, never from a sleep that must end in time."""

from __future__ import annotations

import math
import time

import pytest

from sim2real.deploy.clock import PeriodClock, sleep_until


class _VirtualTime:
    """``time`` for the clock module alone: ``perf_counter`` advances only by the sleeps it is
    asked for and 0.1 ms a look (the spin in ``sleep_until`` ends), whatever the machine does."""

    def __init__(self) -> None:
        self.now = 100.0

    def perf_counter(self) -> float:
        self.now += 1e-4
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += max(0.0, seconds)


def test_an_episodes_first_period_is_not_measured_and_the_next_ones_are(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from sim2real.deploy import clock as clock_mod

    monkeypatch.setattr(clock_mod, "time", _VirtualTime())  # the grid judged, not the load
    clock = PeriodClock(rate_hz=100.0, overrun_warn_fraction=0.2)
    clock.start()
    period_s, late_s = clock.tick()
    assert math.isnan(period_s) and math.isnan(late_s)  # nothing before it, nothing slept to
    for _ in range(3):
        clock.sleep()
        period_s, late_s = clock.tick()
        assert period_s == pytest.approx(clock.period_s, abs=1e-3) and 0.0 <= late_s < 1e-3
    assert len(clock.periods_s) == 3 and len(clock.wake_late_s) == 3 and clock.overruns == 0
    clock.start()  # a new episode: its first period is not measured either
    assert math.isnan(clock.tick()[0]) and len(clock.periods_s) == 3


def test_a_late_period_is_counted_once_and_the_next_starts_at_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clock = PeriodClock(rate_hz=50.0, overrun_warn_fraction=0.2)
    clock.start()
    clock.tick()
    time.sleep(3 * clock.period_s)  # the period's work ran long
    late_end = time.perf_counter()
    clock.sleep()  # nothing to sleep: the next period starts now, no burst to catch up
    period_s, late_s = clock.tick()
    assert period_s >= 3 * clock.period_s and math.isnan(late_s)
    assert clock.overruns == 1 and "overrun: period" in caplog.text
    clock.sleep()  # back on a grid that starts at the late period's end, not before it
    assert time.perf_counter() >= late_end + clock.period_s


def test_restart_makes_a_pause_no_late_period() -> None:
    clock = PeriodClock(rate_hz=50.0, overrun_warn_fraction=0.2)
    clock.start()
    clock.tick()
    time.sleep(5 * clock.period_s)  # paused by a person
    before_restart = time.perf_counter()
    clock.restart()
    clock.sleep()
    period_s, _ = clock.tick()
    # measured from the restart, not from before the pause (however late this runs)
    assert period_s <= time.perf_counter() - before_restart


def test_sleep_until_never_wakes_early() -> None:
    deadline = time.perf_counter() + 0.005
    sleep_until(deadline)
    assert time.perf_counter() >= deadline


def test_a_clock_for_a_lockstep_world_never_sleeps(monkeypatch: pytest.MonkeyPatch) -> None:
    """A lockstep simulator waits for the loop: the loop starts each period as soon as the
    last one's work is done, and no wake-up is counted late."""
    from sim2real.deploy import clock as clock_mod

    virtual = _VirtualTime()
    monkeypatch.setattr(clock_mod, "time", virtual)
    clock = PeriodClock(rate_hz=1.0, overrun_warn_fraction=0.2, sleeps=False)
    clock.start()
    t0 = virtual.now
    for _ in range(5):
        clock.tick()
        clock.sleep()
    assert virtual.now - t0 < 0.01  # paced, five 1 s periods
    assert clock.overruns == 0 and clock.wake_late_s == []
