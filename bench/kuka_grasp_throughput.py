"""Kuka grasping replica throughput: the fast twin against its raw physics+render bound, and the
robosuite IIWA twin, measured in the same run.

Prints one JSON line per figure. The process is pinned to one CPU and llvmpipe rasterises in the
calling thread (``LP_NUM_THREADS=0``), so "on one core" means exactly that. Each figure is taken
in rounds interleaved with the others, so a load swing on this shared machine hits all of them
alike; steps per CPU-second of this process are printed beside steps per wall second because the
CPU figure does not move when other engineers' jobs take the core.

- ``kuka_fast_steps_per_s``: ``Sim2Real/KukaGraspFast-v0`` at 48×48 with ``dr=default``, random
  actions, resets included (target ≥ 500 per CPU-second on one core).
- ``kuka_fast_raw_bound_steps_per_s``: the same model with no env logic: per env step the mean
  number of physics steps an episode spends (control period, grasp phase and reset settling,
  amortised) and one 48×48 frame. ``kuka_fast_fraction_of_bound`` is the env over the bound.
- ``kuka_robosuite_steps_per_s``: ``Sim2Real/KukaGrasp-v0`` (robosuite IIWA) the same way, and
  the fast twin's speed-up over it.
- with ``--baseline-episodes N``: ``kuka_<twin>_random_policy_success``, the grasp success of
  uniformly random discrete actions on the held-out evaluation seeds ``sim2real compare`` uses
  (the floor a trained policy must beat), with its Wilson 95% interval; and
  ``kuka_<twin>_scripted_policy_success``, a privileged scripted servo (it reads the true object
  and target positions, steers onto the nearest object along x/y, leaves yaw alone): what the
  7 actions can achieve when perception is perfect, a practical ceiling for a pixel policy.

Run: ``nice -n 10 .venv/bin/python bench/kuka_grasp_throughput.py [--quick]``.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
os.environ.setdefault("LP_NUM_THREADS", "0")  # llvmpipe renders in this thread: one core
os.environ.setdefault("OMP_NUM_THREADS", "1")

import mujoco
import numpy as np
from support.load import emit_row

from sim2real.envs import kuka_grasp as kg
from sim2real.evaluate.stats import wilson_interval
from sim2real.rendering import FastRenderer
from sim2real.train.config import EVAL_SEED_BASE

TARGET_STEPS_PER_S = 500.0


def emit(metric: str, value: float, unit: str, **extra: object) -> None:
    emit_row({"metric": metric, "value": round(value, 3), "unit": unit, **extra})


class Meter:
    """Accumulates steps, wall seconds and this process's CPU seconds over timed chunks."""

    def __init__(self, chunk: Callable[[], int]) -> None:
        self.chunk = chunk
        self.steps = 0
        self.wall_s = 0.0
        self.cpu_s = 0.0

    def run(self) -> None:
        c0, t0 = time.process_time(), time.perf_counter()
        self.steps += self.chunk()
        self.wall_s += time.perf_counter() - t0
        self.cpu_s += time.process_time() - c0

    @property
    def per_wall_s(self) -> float:
        return self.steps / self.wall_s

    @property
    def per_cpu_s(self) -> float:
        return self.steps / self.cpu_s


def env_chunk(env: kg.KukaGraspBase, steps: int, seed: int) -> Callable[[], int]:
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)

    def chunk() -> int:
        for a in rng.integers(0, 7, steps):
            *_, term, trunc, _ = env.step(int(a))
            if term or trunc:
                env.reset()
        return steps

    return chunk


def raw_bound_chunk(steps: int) -> tuple[Callable[[], int], Callable[[], None]]:
    """Physics and pixels only, on a settled scene of the fast twin's model."""
    env = kg.KukaGraspFastEnv(dr="none")
    env.reset(seed=0)
    m, d = env.model, env.data
    t = env.task
    per_episode = (
        kg.CLOSE_STEPS + kg.LIFT_CHUNKS * kg.LIFT_CHUNK_STEPS + kg.HOLD_STEPS + kg.SETTLE_STEPS
    )
    renderer = FastRenderer(m, 48, 48)
    done = [0]

    def chunk() -> int:
        for _ in range(steps):
            mujoco.mj_step(m, d, nstep=env.frame_skip)
            done[0] += 1
            if done[0] % t.descent_steps == 0:  # one grasp phase and one reset per episode
                mujoco.mj_step(m, d, nstep=per_episode)
                renderer.render(d, kg.CAMERA)
            renderer.render(d, kg.CAMERA)
        return steps

    def close() -> None:
        renderer.close()
        env.close()

    return chunk, close


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer rounds (a smoke run)")
    parser.add_argument("--no-robosuite", action="store_true", help="skip the robosuite twin")
    parser.add_argument(
        "--baseline-episodes", type=int, default=0, help="random-policy episodes per twin"
    )
    args = parser.parse_args()
    rounds = 2 if args.quick else 6
    cpu = sorted(os.sched_getaffinity(0))[-1]
    os.sched_setaffinity(0, {cpu})

    fast_env = kg.KukaGraspFastEnv(dr="default")
    fast = Meter(env_chunk(fast_env, 300, 0))
    raw_fn, raw_close = raw_bound_chunk(300)
    bound = Meter(raw_fn)
    meters = [fast, bound]
    rs_env = None
    if not args.no_robosuite:
        from sim2real.envs.kuka_robosuite import KukaGraspEnv

        rs_env = KukaGraspEnv(dr="default")
        robo = Meter(env_chunk(rs_env, 24, 0))
        meters.append(robo)
    for meter in meters:  # warm-up: first frames build GL state
        meter.chunk()
    load_before = os.getloadavg()[0]
    for _ in range(rounds):
        for meter in meters:
            meter.run()
    load = round((load_before + os.getloadavg()[0]) / 2, 2)
    common = {"image_px": 48, "cpu_pinned": cpu, "loadavg_1min": load}
    emit(
        "kuka_fast_steps_per_s",
        fast.per_cpu_s,
        "env steps per CPU-second (one core)",
        wall_steps_per_s=round(fast.per_wall_s, 1),
        target=TARGET_STEPS_PER_S,
        **{"pass": fast.per_cpu_s >= TARGET_STEPS_PER_S},
        **common,
    )
    emit(
        "kuka_fast_raw_bound_steps_per_s",
        bound.per_cpu_s,
        "physics+render steps per CPU-second",
        wall_steps_per_s=round(bound.per_wall_s, 1),
        **common,
    )
    emit(
        "kuka_fast_fraction_of_bound",
        fast.per_cpu_s / bound.per_cpu_s,
        "ratio (env / raw bound, CPU time)",
        **common,
    )
    if rs_env is not None:
        robo = meters[2]
        emit(
            "kuka_robosuite_steps_per_s",
            robo.per_cpu_s,
            "env steps per CPU-second (one core)",
            wall_steps_per_s=round(robo.per_wall_s, 1),
            **common,
        )
        emit(
            "kuka_fast_speedup_over_robosuite",
            fast.per_cpu_s / robo.per_cpu_s,
            "ratio (CPU time)",
            **common,
        )
    if args.baseline_episodes > 0:
        twins: list[tuple[str, kg.KukaGraspBase]] = [("fast", fast_env)]
        if rs_env is not None:
            twins.append(("robosuite", rs_env))
        for name, env in twins:
            n = args.baseline_episodes if name == "fast" else max(1, args.baseline_episodes // 4)
            for policy, successes in (
                ("random", random_policy_successes),
                ("scripted", scripted_policy_successes),
            ):
                wins = successes(env, n)
                lo, hi = wilson_interval(wins, n)
                emit(
                    f"kuka_{name}_{policy}_policy_success",
                    wins / n,
                    "fraction of held-out episodes",
                    wilson95=[round(lo, 3), round(hi, 3)],
                    episodes=n,
                    dr="default",
                )
    if rs_env is not None:
        rs_env.close()
    fast_env.close()
    raw_close()


def random_policy_successes(env: kg.KukaGraspBase, episodes: int) -> int:
    """Uniform random discrete actions on seeds EVAL_SEED_BASE + j, as ``compare`` evaluates."""
    rng = np.random.default_rng(0)
    wins = 0
    for j in range(episodes):
        env.reset(seed=EVAL_SEED_BASE + j)
        term = False
        info: dict[str, object] = {}
        while not term:
            _, _, term, _, info = env.step(int(rng.integers(0, 7)))
        wins += bool(info["is_success"])
    return wins


def scripted_action(env: kg.KukaGraspBase, slot: int) -> int:
    """One of the 7 actions: the larger horizontal error to ``slot``'s object, or descend only
    when both are within half a step."""
    err = env.object_positions()[slot, :2] - env.target_pose()[:2]
    if np.max(np.abs(err)) < 0.5 * env.task.xy_step_m:
        return 0
    axis = int(np.argmax(np.abs(err)))
    return 1 + 2 * axis + int(err[axis] < 0)  # +x, -x, +y, -y are actions 1, 2, 3, 4


def scripted_policy_successes(env: kg.KukaGraspBase, episodes: int) -> int:
    """The privileged servo onto the object nearest the start, on the same held-out seeds."""
    wins = 0
    for j in range(episodes):
        env.reset(seed=EVAL_SEED_BASE + j)
        d = env.object_positions()[:, :2] - env.gripper_pose()[:2]
        slot = int(np.argmin(np.einsum("ij,ij->i", d, d)))
        term = False
        info: dict[str, object] = {}
        while not term:
            _, _, term, _, info = env.step(scripted_action(env, slot))
        wins += bool(info["is_success"])
    return wins


if __name__ == "__main__":
    main()
