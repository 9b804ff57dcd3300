"""What an ``Arm3Reach-v0`` reset costs (DR default), warm and inside a step loop.

Prints JSON lines: microseconds of CPU time per reset in a tight loop of resets ("warm") and per
reset inside a bench-shaped loop of 3,000 steps with a reset every 50 ("in the loop", where the
physics steps between resets have evicted the reset's code and data). Best of ``BENCH_ROUNDS``.
To compare two trees, run this file against each in turn (``PYTHONPATH=<tree>``) and alternate:
the machine's load moves both figures by ±30 %. Run: make bench.
"""

from __future__ import annotations

import os
import platform
import sys
import time

import gymnasium as gym
import numpy as np

import sim2real.envs  # noqa: F401

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from support.load import emit

ROUNDS = int(os.environ.get("BENCH_ROUNDS", "3"))
RESETS = 2000
STEPS = 3000
clock = time.process_time


def main() -> None:
    env = gym.make("Sim2Real/Arm3Reach-v0", dr="default")
    env.reset(seed=0)
    warm = []
    for _ in range(ROUNDS):
        t0 = clock()
        for _ in range(RESETS):
            env.reset()
        warm.append((clock() - t0) / RESETS)
    actions = np.random.default_rng(0).uniform(-1, 1, (STEPS, *env.action_space.shape))
    actions = actions.astype(np.float32)
    in_loop = []
    for _ in range(ROUNDS):
        spent, n = 0.0, 0
        for a in actions:
            *_, term, trunc, _ = env.step(a)
            if term or trunc:
                t0 = clock()
                env.reset()
                spent += clock() - t0
                n += 1
        in_loop.append(spent / n)
    env.close()
    machine = {
        "machine": f"{platform.machine()} {os.cpu_count()} cpu",
        "python": platform.python_version(),
        "load_avg_1min": round(os.getloadavg()[0], 1),
    }
    for metric, values in (("reach_reset_warm_us", warm), ("reach_reset_in_loop_us", in_loop)):
        emit(metric, round(min(values) * 1e6, 1), "us", **machine)


if __name__ == "__main__":
    main()
