"""Cost of the workspace guard in the safety filter, which runs once every control period.

Prints JSON lines: the time per ``SafetyFilter.filter`` call with the guard and, in the same run,
the same filter with the guard step skipped (the reference), for commands inside the workspace
(the hot path: one FK) and for commands the guard has to shorten (subsets + bisection). The
figure to read is the ratio; the microseconds depend on the machine's load.

    .venv/bin/python bench/safety_filter.py [--calls 20000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import logging
import time
from collections.abc import Callable

import numpy as np
from support.load import emit_row

from hardware.safety import SafetyFilter
from hardware.spec import load_spec


def _best_us(fn: Callable[[], object], calls: int, repeats: int) -> float:
    """The fastest of ``repeats`` runs of ``calls`` calls, in µs per call (load only adds)."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        best = min(best, (time.perf_counter() - t0) / calls)
    return best * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    logging.disable(logging.WARNING)  # the guard's one warning is not the subject here

    spec = load_spec()
    guarded = SafetyFilter(spec)
    reference = SafetyFilter(spec)
    reference._guard_workspace = lambda q, prev: q  # type: ignore[method-assign]

    home = spec.actuator_home_rad
    inside = home + np.array([0.05, 0.05, -0.05, 0.1])
    low = np.array([0.0, 0.8, 0.3, 0.0])  # tool 22 mm above the table
    dive = np.array([0.0, 1.3, 0.27, 0.0])  # straight into the table
    assert guarded.guard.inside(inside) and guarded.guard.inside(low)
    assert not guarded.guard.inside(dive)

    cases = {
        "inside": (inside, home),
        "shortened": (dive, low),
    }
    for name, (target, prev) in cases.items():
        before = guarded.stats.workspace_clamped
        with_us = _best_us(lambda t=target, p=prev: guarded.filter(t, p), args.calls, args.repeats)
        ref_us = _best_us(lambda t=target, p=prev: reference.filter(t, p), args.calls, args.repeats)
        emit_row(
            {
                "bench": "safety_filter",
                "case": name,
                "guard_changed_command": guarded.stats.workspace_clamped > before,
                "us_per_call": round(with_us, 2),
                "reference_us_per_call": round(ref_us, 2),
                "ratio": round(with_us / ref_us, 3),
                "added_us": round(with_us - ref_us, 2),
                "calls": args.calls,
                "repeats": args.repeats,
            }
        )


if __name__ == "__main__":
    main()
