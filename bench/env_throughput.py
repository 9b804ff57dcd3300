"""Env throughput: our envs against their own physics bound, Gymnasium Reacher-v5 and robosuite.

Prints one JSON line per figure. Speeds are compared as ratios measured in this same run
(interleaved rounds, best round of each), so machine load cancels out. Rates are steps per CPU
second of this process (``BENCH_CLOCK=wall`` for wall-clock seconds): the project's machine is
shared, and other jobs stretch wall time by whatever they happen to run, not CPU time. Run: make
bench.
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import gymnasium as gym
import mujoco
import numpy as np
from support.load import emit_row

import sim2real.envs  # noqa: F401

STEPS = int(os.environ.get("BENCH_STEPS", "3000"))
CLOCK_NAME = os.environ.get("BENCH_CLOCK", "cpu")
clock = time.perf_counter if CLOCK_NAME == "wall" else time.process_time
ROUNDS = int(os.environ.get("BENCH_ROUNDS", "3"))


def env_rate(
    env_id: str, steps: int, record: list[np.ndarray] | None = None, **kw: object
) -> float:
    env = gym.make(env_id, **kw)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, *env.action_space.shape)).astype(np.float32)
    t0 = clock()
    for a in actions:
        *_, term, trunc, _ = env.step(a)
        if record is not None:
            record.append(env.unwrapped.data.ctrl.copy())
        if term or trunc:
            env.reset()
    rate = steps / (clock() - t0)
    env.close()
    return rate


def physics_bound(env_id: str, ctrls: list[np.ndarray]) -> float:
    """mj_step × frame_skip on the same model, replaying the env's own actuator commands."""
    env = gym.make(env_id, dr="none")
    u = env.unwrapped
    model, data = u.model, mujoco.MjData(u.model)
    env.reset(seed=0)
    data.qpos[:] = u.data.qpos
    skip = u.frame_skip
    t0 = clock()
    for i, c in enumerate(ctrls):
        data.ctrl[:] = c
        mujoco.mj_step(model, data, nstep=skip)
        if (i + 1) % 50 == 0:
            mujoco.mj_resetData(model, data)
    rate = len(ctrls) / (clock() - t0)
    env.close()
    return rate


def robosuite_lift_rate(steps: int) -> float:
    import robosuite

    env = robosuite.make(
        "Lift",
        robots="Panda",
        has_renderer=False,
        has_offscreen_renderer=False,
        use_camera_obs=False,
        hard_reset=False,
        control_freq=20,
    )
    env.reset()
    low, high = env.action_spec
    rng = np.random.default_rng(0)
    t0 = clock()
    for i in range(steps):
        env.step(rng.uniform(low, high))
        if (i + 1) % 500 == 0:
            env.reset()
    rate = steps / (clock() - t0)
    env.close()
    return rate


def best_of(fn: Callable[[], float]) -> float:
    return max(fn() for _ in range(ROUNDS))


def emit(metric: str, value: float, unit: str, **extra: object) -> None:
    emit_row({"metric": metric, "value": round(value, 3), "unit": unit, **extra})


def main() -> None:
    import torch

    torch.set_num_threads(1)
    reach_ctrls: list[np.ndarray] = []
    env_rate("Sim2Real/Arm3Reach-v0", STEPS, record=reach_ctrls, dr="default")
    pick_ctrls: list[np.ndarray] = []
    env_rate("Sim2Real/Arm3Pick-v0", STEPS, record=pick_ctrls, dr="default")

    rates: dict[str, list[float]] = {
        k: [] for k in ("reach", "reach_bound", "pick", "pick_bound", "pixels", "reacher")
    }
    for _ in range(ROUNDS):  # interleaved so load affects every figure alike
        rates["reach"].append(env_rate("Sim2Real/Arm3Reach-v0", STEPS, dr="default"))
        rates["reach_bound"].append(physics_bound("Sim2Real/Arm3Reach-v0", reach_ctrls))
        rates["pick"].append(env_rate("Sim2Real/Arm3Pick-v0", STEPS, dr="default"))
        rates["pick_bound"].append(physics_bound("Sim2Real/Arm3Pick-v0", pick_ctrls))
        rates["pixels"].append(env_rate("Sim2Real/Arm3ReachPixels-v0", STEPS // 3, dr="default"))
        rates["reacher"].append(env_rate("Reacher-v5", STEPS))
    best = {k: max(v) for k, v in rates.items()}
    machine = {
        "machine": f"{platform.machine()} {os.cpu_count()} cpu",
        "python": platform.python_version(),
        "clock": CLOCK_NAME,
        "load_avg_1min": round(os.getloadavg()[0], 1),
    }
    emit("arm3reach_steps_per_s", best["reach"], "steps/s", dr="default", **machine)
    emit("arm3reach_physics_bound_steps_per_s", best["reach_bound"], "steps/s")
    ratio = best["reach"] / best["reach_bound"]
    emit("arm3reach_vs_physics_bound", ratio, "ratio", target=0.7, passed=ratio >= 0.7)
    emit("reacher_v5_steps_per_s", best["reacher"], "steps/s")
    ratio = best["reach"] / best["reacher"]
    emit("arm3reach_vs_reacher_v5", ratio, "ratio", target=1.0, passed=ratio >= 1.0)
    emit("arm3pick_steps_per_s", best["pick"], "steps/s", dr="default")
    emit("arm3pick_vs_physics_bound", best["pick"] / best["pick_bound"], "ratio")
    emit(
        "arm3reach_pixels84_steps_per_s",
        best["pixels"],
        "steps/s",
        target=500,
        passed=best["pixels"] >= 500,
    )
    try:
        lift = best_of(lambda: robosuite_lift_rate(max(STEPS // 5, 200)))
    except Exception as exc:  # robosuite missing or broken: say so, do not fake it
        emit("robosuite_lift_steps_per_s", float("nan"), "steps/s", error=str(exc).splitlines()[0])
        return
    emit("robosuite_lift_steps_per_s", lift, "steps/s", robot="Panda", hard_reset=False)
    ratio = best["pick"] / lift
    emit("arm3pick_vs_robosuite_lift", ratio, "ratio", target=50, passed=ratio >= 50)


if __name__ == "__main__":
    main()
