"""What issue 15's learning methods cost in training speed on Sim2Real/KukaGraspFast-v0.

Each variant trains from scratch with its shipped preset for a short budget (PPO: two rollouts of
8 envs x 256 steps, so one full update per rollout is included; DQN: past ``learning_starts``,
so most steps carry a gradient update; distill: several DAgger iterations), in rounds
interleaved with the plain preset, so a load swing on this shared machine hits all of them alike.
Speed is env steps per CPU-second of this process (pinned to one core, torch on one thread,
llvmpipe rendering in the calling thread), printed beside steps per wall second; the figure that
matters is the ratio to the plain algorithm measured in the same run (target <= 1.5x its cost).

- ``pixels_<variant>_steps_per_cpu_s`` for ppo (plain), ppo_drq (random shift), ppo_asym
  (shift + privileged critic), dqn (plain), dqn_double_nstep (double Q + 3-step + shift) and
  distill (DAgger from the scripted servo);
- ``pixels_<variant>_cost_vs_<plain>``: plain speed / variant speed (1.0 = free).

Run: ``nice -n 10 .venv/bin/python bench/train_pixels_cost.py [--quick] [--rounds N]``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
os.environ.setdefault("LP_NUM_THREADS", "0")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch as th
from support.load import emit_row

from sim2real.train import resolve_config, train

TARGET_COST = 1.5
# variant -> (algo, preset, the plain variant it is compared with, overrides)
VARIANTS: dict[str, tuple[str, str, str, list[str]]] = {
    "ppo": ("ppo", "ppo_kuka_fast", "ppo", []),
    "ppo_drq": ("ppo", "ppo_kuka_fast_drq", "ppo", []),
    "ppo_asym": ("ppo", "ppo_kuka_fast_asym", "ppo", []),
    "dqn": ("dqn", "dqn_kuka_fast", "dqn", ["learning_starts=500", "buffer_size=5000"]),
    "dqn_double_nstep": (
        "dqn",
        "dqn_kuka_fast_double_nstep",
        "dqn",
        ["learning_starts=500", "buffer_size=5000"],
    ),
    "distill": ("distill", "distill_kuka_fast", "ppo", ["dataset_size=5000"]),
}
STEPS = {"ppo": 4096, "dqn": 2500, "distill": 4096}
QUICK_STEPS = {"ppo": 2048, "dqn": 1200, "distill": 2048}


def emit(metric: str, value: float, unit: str, **extra: object) -> None:
    emit_row({"metric": metric, "value": round(value, 4), "unit": unit, **extra})


def run_once(variant: str, steps: int, dr: str, root: Path) -> tuple[float, float]:
    """(env steps per CPU-second, per wall second) of one short training run from scratch."""
    algo, preset, _, extra = VARIANTS[variant]
    run_dir = root / f"{variant}-{time.monotonic_ns()}"
    cfg = resolve_config(
        "kuka-fast",
        algo,
        run_dir,
        dr=dr,
        steps=steps,
        preset=preset,
        progress=False,
        overrides=["checkpoint_every=1000000", *extra],
    )
    c0, w0 = time.process_time(), time.perf_counter()
    result = train(cfg)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    shutil.rmtree(run_dir, ignore_errors=True)
    return result.steps_done / cpu, result.steps_done / wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="half the budgets (a smoke run)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--dr", default="default", help="DR preset of the training envs")
    ap.add_argument("--only", nargs="*", default=list(VARIANTS), choices=list(VARIANTS))
    args = ap.parse_args()
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    th.set_num_threads(1)
    budgets = QUICK_STEPS if args.quick else STEPS
    names = [v for v in VARIANTS if v in args.only]
    for v in names:  # the plain variant each is compared with is measured too
        if VARIANTS[v][2] not in names:
            names.insert(0, VARIANTS[v][2])
    names = list(dict.fromkeys(names))
    cpu: dict[str, list[float]] = {v: [] for v in names}
    wall: dict[str, list[float]] = {v: [] for v in names}
    with tempfile.TemporaryDirectory(prefix="pixcost-") as tmp:
        for _ in range(args.rounds):
            for v in names:
                c, w = run_once(v, budgets[VARIANTS[v][0]], args.dr, Path(tmp))
                cpu[v].append(c)
                wall[v].append(w)
    common = {"env": "Sim2Real/KukaGraspFast-v0", "dr": args.dr, "rounds": args.rounds}
    for v in names:
        algo, preset, plain, _ = VARIANTS[v]
        mean_cpu = sum(cpu[v]) / len(cpu[v])
        emit(
            f"pixels_{v}_steps_per_cpu_s",
            mean_cpu,
            "steps/cpu-s",
            preset=preset,
            steps=budgets[algo],
            steps_per_wall_s=round(sum(wall[v]) / len(wall[v]), 2),
            **common,
        )
        if v != plain:
            cost = (sum(cpu[plain]) / len(cpu[plain])) / mean_cpu
            emit(
                f"pixels_{v}_cost_vs_{plain}",
                cost,
                "x",
                target=f"<= {TARGET_COST}",
                met=cost <= TARGET_COST,
                **common,
            )


if __name__ == "__main__":
    main()
