"""How well a privileged reach teacher (``distill``'s ``reach_ik`` or ``reach_servo``,
``reach.ReachServo``) itself reaches: the ceiling a distilled pixel student of
``Sim2Real/Arm3ReachPixels-v0`` can approach.

The teacher drives the real pixel env (frames rendered, as in training) from
``info["privileged_state"]`` alone, built for the env's own action decoding, on held-out
evaluation seeds. Success is the env's, judged on the final step, at ``--threshold-m`` (the
``distill_reach_pixels`` preset's 2 cm), and at 1 cm beside it.

Prints one JSON line per teacher and DR preset: ``reach_teacher_success`` (value = success rate at the
threshold) with its Wilson interval, the 1 cm rate, median / 95th percentile / largest final
distance (mm), the steps on which neither IK aim was reachable (the teacher held: an all-zero
action) and env steps per CPU-second.

Run: ``nice -n 15 .venv/bin/python bench/reach_teacher.py [--episodes 300] [--dr default,shifted]
[--teacher reach_ik,reach_servo]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
os.environ.setdefault("LP_NUM_THREADS", "0")

import numpy as np

import sim2real.envs as envs
from sim2real.evaluate.stats import wilson_interval
from sim2real.train.config import EVAL_SEED_BASE
from sim2real.train.distill import get_teacher

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from support.load import emit


def run(name: str, dr: str, episodes: int, threshold_m: float) -> None:
    env = envs.make("reach-pixels", dr=dr, success_threshold_m=threshold_m)
    teacher = get_teacher(name, env.unwrapped.decoder)  # type: ignore[attr-defined]
    final_m, wins, holds, steps = [], 0, 0, 0
    t0 = time.process_time()
    try:
        for j in range(episodes):
            _, info = env.reset(seed=EVAL_SEED_BASE + j)
            done = False
            while not done:
                action = teacher.action(info["privileged_state"])
                holds += not np.any(action)
                _, _, term, trunc, info = env.step(action)
                done, steps = term or trunc, steps + 1
            final_m.append(info["distance_m"])
            wins += bool(info["is_success"])
    finally:
        env.close()
    d_mm = 1000.0 * np.array(final_m)
    lo, hi = wilson_interval(wins, episodes)
    emit(
        "reach_teacher_success",
        round(wins / episodes, 4),
        "fraction",
        teacher=name,
        dr=dr,
        episodes=episodes,
        threshold_m=threshold_m,
        wilson95=[round(lo, 4), round(hi, 4)],
        success_1cm=round(float(np.mean(d_mm < 10.0)), 4),
        median_final_mm=round(float(np.median(d_mm)), 2),
        p95_final_mm=round(float(np.percentile(d_mm, 95)), 2),
        max_final_mm=round(float(d_mm.max()), 2),
        no_aim_steps=holds,
        steps_per_cpu_s=round(steps / max(time.process_time() - t0, 1e-9), 1),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=300)
    ap.add_argument("--dr", default="default", help="comma-separated DR presets")
    ap.add_argument("--threshold-m", type=float, default=0.02)
    ap.add_argument("--teacher", default="reach_ik,reach_servo", help="comma-separated teachers")
    args = ap.parse_args()
    for name in args.teacher.split(","):
        for dr in args.dr.split(","):
            run(name, dr, args.episodes, args.threshold_m)


if __name__ == "__main__":
    main()
