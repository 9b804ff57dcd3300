"""What an arm env step costs (DR default), through ``gym.make`` and on ``env.unwrapped``.

Prints JSON lines: microseconds of CPU time per step in a bench-shaped loop (random actions, a
reset whenever an episode ends, resets included), best of ``BENCH_ROUNDS``, for the env as
``gym.make`` returns it and for ``env.unwrapped``; then the same loop with ``mujoco.mj_step``
replaced by a no-op ("without physics": what the env's own code costs, warm). ``BENCH_ENV``
picks the id (default ``Sim2Real/Arm3Pick-v0``). To compare two trees, run this file against
each in turn (``PYTHONPATH=<tree>``) and alternate: load moves the in-loop figures by ±5 %.
Run: make bench.
"""

from __future__ import annotations

import os
import platform
import sys
import time
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

import sim2real.envs  # noqa: F401

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from support.load import emit

ENV_ID = os.environ.get("BENCH_ENV", "Sim2Real/Arm3Pick-v0")
ROUNDS = int(os.environ.get("BENCH_ROUNDS", "3"))
STEPS = int(os.environ.get("BENCH_STEPS", "6000"))
clock = time.process_time


def loop_us(env: Any, actions: np.ndarray) -> float:
    step, reset = env.step, env.reset
    t0 = clock()
    for a in actions:
        *_, term, trunc, _ = step(a)
        if term or trunc:
            reset()
    return (clock() - t0) / len(actions) * 1e6


def best(fn: Callable[[], float]) -> float:
    return min(fn() for _ in range(ROUNDS))


def main() -> None:
    env = gym.make(ENV_ID, dr="default")
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (STEPS, *env.action_space.shape))
    actions = actions.astype(np.float32)
    loop_us(env, actions[:500])  # compiled kernels loaded, caches warm
    made = best(lambda: loop_us(env, actions))
    bare = best(lambda: loop_us(env.unwrapped, actions))
    physics = mujoco.mj_step
    mujoco.mj_step = lambda m, d, nstep=1: None
    try:
        own = best(lambda: loop_us(env, actions))
    finally:
        mujoco.mj_step = physics
    env.close()
    where = {
        "env": ENV_ID,
        "machine": f"{platform.machine()} {os.cpu_count()} cpu",
        "load_avg_1min": round(os.getloadavg()[0], 1),
    }
    emit("step_us_gym_make", round(made, 2), "us/step", **where)
    emit("step_us_unwrapped", round(bare, 2), "us/step")
    emit("step_us_without_physics", round(own, 2), "us/step")


if __name__ == "__main__":
    main()
