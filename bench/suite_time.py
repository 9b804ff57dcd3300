"""How long ``make test``'s pytest takes, beside this machine's speed measured in the same run.

The suite's wall time says little alone: the project's 2-core VMs have differed twofold in
speed from one day to the next (the pick env stepped 8,494 times per CPU second on 2026-11-24
and 4,200 on 2026-12-07). So the bench steps the pick env on one core (steps per CPU second,
the best of three rounds, as ``env_throughput.py``) before and after the suite, and reports
the suite's seconds, its counts, that speed, and the seconds scaled to ``REFERENCE_STEPS_PER_S``
(the speed of the VM on which issue 39's 300 s target was set). The scaled figure is an
estimate, and a kind one: the suite's waits on wall clocks (20 Hz loops, child processes) do
not shrink on a faster machine.

    python bench/suite_time.py                  # make test's pytest, as a fresh clone runs it
    python bench/suite_time.py --busy 2         # with two busy processes beside it
    python bench/suite_time.py --slow           # the slow set (make test-slow)
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from env_throughput import env_rate  # steps per CPU second unless BENCH_CLOCK=wall
from support.load import REPO, emit_row

REFERENCE_STEPS_PER_S = 8494.0  # arm3pick, one core, bench/records/speed.jsonl, 2026-11-24
TARGET_S = {"default": 300.0, "slow": None}
PYTEST = {
    "default": ["-n", "2", "--timeout", "600", "-q"],
    "slow": ["-n", "2", "--timeout", "3600", "-q", "-m", "slow"],
}
_SUMMARY = re.compile(r"=* ?(?P<counts>[^=]*?) in (?P<s>[0-9.]+)s")


def pick_steps_per_cpu_s(rounds: int = 3) -> float:
    """The pick env's steps per CPU second of this process, best of ``rounds``."""
    return max(env_rate("Sim2Real/Arm3Pick-v0", 3000, dr="default") for _ in range(rounds))


def clear_bytecode() -> int:
    """Remove the project's ``__pycache__`` folders (not the venv's): a fresh clone has none."""
    found = [
        p for p in REPO.rglob("__pycache__") if ".venv" not in p.parts and ".git" not in p.parts
    ]
    for p in found:
        shutil.rmtree(p, ignore_errors=True)
    return len(found)


def counts(summary: str) -> dict[str, int]:
    """``1613 passed, 1 skipped, 2 warnings`` → {"passed": 1613, "skipped": 1, "warnings": 2}."""
    out = {}
    for part in summary.split(","):
        n, _, what = part.strip().partition(" ")
        if n.isdigit():
            out[what] = int(n)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--busy", type=int, default=0, help="busy processes beside the suite")
    ap.add_argument("--slow", action="store_true", help="the slow set (make test-slow)")
    ap.add_argument("--keep-bytecode", action="store_true", help="keep the project's __pycache__")
    args = ap.parse_args()
    if args.busy < 0:
        ap.error(f"--busy must be >= 0, got {args.busy}")
    which = "slow" if args.slow else "default"
    speed_before = pick_steps_per_cpu_s()
    if not args.keep_bytecode:
        clear_bytecode()
    env = {**os.environ, "SIM2REAL_REQUIRE_AVR": "1"}
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # as make test: the workers share compiled modules
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
    try:
        t0 = time.perf_counter()
        res = subprocess.run(
            [sys.executable, "-m", "pytest", *PYTEST[which]],
            cwd=REPO, env=env, capture_output=True, text=True,
        )  # fmt: skip
        wall_s = time.perf_counter() - t0
    finally:
        for p in busy:
            p.kill()
            p.wait()
    speed_after = pick_steps_per_cpu_s()
    last = res.stdout.strip().splitlines()[-1] if res.stdout.strip() else ""
    found = _SUMMARY.search(last)
    if found is None:
        print(f"error: no pytest summary in its output; last line: {last!r}", file=sys.stderr)
        return 1
    pytest_s = float(found["s"])
    speed = 0.5 * (speed_before + speed_after)
    target = TARGET_S[which] if args.busy == 0 else None  # under load: green is the target
    scaled_s = pytest_s * speed / REFERENCE_STEPS_PER_S
    emit_row(
        {
            "metric": f"suite_{which}_pytest_s",
            "label": f"`make {'test-slow' if args.slow else 'test'}`'s pytest on 2 workers, "
            + (f"{args.busy} busy processes beside it" if args.busy else "idle"),
            "value": round(pytest_s, 1),
            "unit": "s",
            "variant": f"busy{args.busy}" if args.busy else "idle",
            "target": f"<= {target:.0f} s (scaled)" if target else "",
            "passed": res.returncode == 0 and (target is None or scaled_s <= target),
            "table": "The test suite (issue 39)",
            "note": (
                f"{last.strip('= ')}; {args.busy} busy processes beside it; this machine's pick "
                f"env {speed:.0f} steps/CPU-s ({speed_before:.0f} before, {speed_after:.0f} "
                f"after); scaled to {REFERENCE_STEPS_PER_S:.0f} steps/s: {scaled_s:.0f} s; "
                f"wall {wall_s:.0f} s with start-up"
            ),
            **{f"tests_{k}": v for k, v in counts(found["counts"]).items()},
            "pick_steps_per_cpu_s": round(speed),
            "scaled_s": round(scaled_s, 1),
            "pytest_rc": res.returncode,
        }
    )
    return 0 if res.returncode == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
