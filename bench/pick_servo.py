"""The ceiling of pick: the privileged scripted teacher (``distill``'s ``pick_servo``,
``pick.PickServo``) on held-out episodes, with a breakdown of its failures.

The teacher acts from ``Arm3Env.privileged_state`` alone (the true joints, gripper reading,
tool, cube, what the safety filter sent and the lift goal), built for the env's own action
decoding, through the host's safety filter as the shipped pick policies train (``safety_filter``).
Success is the env's: the cube within 2 cm of the point 7 cm above where it was put down, at the
episode's last step. A failed episode is put in one class, judged from the truth:

* ``never grasped`` (both fingers never touched the cube at once);
* ``pushed before the grasp`` (the cube moved > 2 cm on the table before the first grasp: the
  lift goal stays where it was put down);
* ``dropped`` (lifted > 2 cm, then back on the table);
* ``short of the goal`` (held at the end, not within 2 cm of it: slipping, or out of time).

Prints one JSON line per DR preset: ``pick_teacher_success`` (value = success rate) with its
Wilson interval, the failure classes, the median step of the first success, and env steps per
CPU-second.

With ``--backends sim,mock`` the same teacher also runs through the deploy loop on those
backends (``pick_teacher_deploy_success``, on the placements of the env's held-out episodes).

Run: ``nice -n 15 .venv/bin/python bench/pick_servo.py [--episodes 200] [--dr default,none]
[--backends sim,mock] [--record training]``.
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import time

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np

import sim2real.envs as envs
from sim2real.evaluate.stats import wilson_interval
from sim2real.train.config import EVAL_SEED_BASE
from sim2real.train.distill import get_teacher

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from support.load import emit

PUSHED_M = 0.02  # the success ball's radius: a cube pushed further cannot succeed
LIFTED_M = 0.02


def _episode(env: envs.Arm3Env, teacher: object, seed: int) -> tuple[bool, str, int | None]:
    """(success, failure class or "", the step it first succeeded at)."""
    u = env.unwrapped
    env.reset(seed=seed)
    task = u.task
    rest = task.cube_position(u).copy()
    grasped = False
    pushed_m = peak_m = 0.0
    first: int | None = None
    info: dict[str, object] = {}
    for k in range(u.max_episode_steps):
        _, _, _, _, info = env.step(teacher.action(u.privileged_state()))  # type: ignore[attr-defined]
        cube = task.cube_position(u)
        grasped = grasped or task.is_grasped(u)
        if not grasped:
            pushed_m = max(pushed_m, float(np.linalg.norm(cube[:2] - rest[:2])))
        peak_m = max(peak_m, float(cube[2] - rest[2]))
        if first is None and info["is_success"]:
            first = k
    if info["is_success"]:
        return True, "", first
    if not grasped:
        return False, "never grasped", first
    if pushed_m > PUSHED_M:
        return False, "pushed before the grasp", first
    if peak_m > LIFTED_M and not task.is_grasped(u):
        return False, "dropped", first
    return False, "short of the goal", first


def run(dr: str, episodes: int) -> None:
    env = envs.make("pick", dr=dr, safety_filter=True)
    teacher = get_teacher("pick_servo", env.unwrapped.decoder)  # type: ignore[attr-defined]
    wins, classes, firsts = 0, collections.Counter[str](), []
    t0 = time.process_time()
    try:
        for j in range(episodes):
            ok, why, first = _episode(env, teacher, EVAL_SEED_BASE + j)
            wins += ok
            if why:
                classes[why] += 1
            if first is not None:
                firsts.append(first)
    finally:
        env.close()
    cpu_s = time.process_time() - t0
    lo, hi = wilson_interval(wins, episodes)
    steps = episodes * env.unwrapped.max_episode_steps  # type: ignore[attr-defined]
    emit(
        "pick_teacher_success",
        round(wins / episodes, 4),
        "fraction",
        label=f"scripted pick on the truth (`pick_servo`), held-out success, DR `{dr}`",
        table="Pick: the privileged teacher (the ceiling)",
        variant=dr,
        teacher="pick_servo",
        dr=dr,
        episodes=episodes,
        ci95=[round(lo, 4), round(hi, 4)],
        failures=dict(classes),
        median_first_success_step=float(np.median(firsts)) if firsts else None,
        env_steps_per_cpu_s=round(steps / cpu_s, 1),
    )


def deploy(backend: str, episodes: int, policy: str) -> None:
    """The teacher through the deploy loop on ``backend`` (sim: lockstep MuJoCo, ground-truth
    perception; mock: the emulated firmware on a pty, MuJoCo physics, rendered cameras),
    reading the world's truth (``deploy.privileged.TruthTeacher``), on the held-out placements
    ``evaluate`` uses under DR ``none``. ``policy`` (a shipped pick policy) lends its
    observation layout and control rate; its own actor is not used."""
    from hardware.spec import load_spec
    from sim2real.deploy.policy_io import policy_io
    from sim2real.deploy.privileged import TruthTeacher
    from sim2real.deploy.runner import DeployOptions, run_policy
    from sim2real.deploy.session import LoopConfig
    from sim2real.envs.pick import lift_goal
    from sim2real.held_out import EvalTarget, held_out_placements

    spec = load_spec()
    target = EvalTarget.load(policy)
    io = policy_io(spec, target.policy.meta)
    teacher = get_teacher("pick_servo", io.decoder)
    placements = tuple(held_out_placements(target, episodes))
    truth = TruthTeacher(teacher.action, io, extra=lambda view: lift_goal(view.objects["cube"]))
    t0 = time.perf_counter()
    res = run_policy(truth, io, spec, DeployOptions(backend=backend),
                     LoopConfig(episodes=episodes, placements=placements))  # fmt: skip
    s = res.summary().to_json()
    wins = res.successes
    lo, hi = wilson_interval(wins, episodes)
    emit(
        "pick_teacher_deploy_success",
        round(wins / episodes, 4),
        "fraction",
        label=f"scripted pick on the truth through the deploy loop, `{backend}` backend",
        table="Pick: the privileged teacher (the ceiling)",
        variant=backend,
        teacher="pick_servo",
        episodes=episodes,
        ci95=[round(lo, 4), round(hi, 4)],
        stops=s["episode_stops"],
        loop_hz=round(s["loop_hz"], 2),
        p99_jitter_ms=round(s["period_jitter_ms"]["p99"], 2),
        wall_s=round(time.perf_counter() - t0, 1),
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", type=int, default=200)
    p.add_argument("--dr", default="default,none")
    p.add_argument(
        "--backends", default="", help="comma list of deploy backends (sim, mock) to run it on"
    )
    p.add_argument("--policy", default="pick-ppo", help="a shipped pick policy: its layout")
    a = p.parse_args()
    for dr in a.dr.split(","):
        if dr:
            run(dr, a.episodes)
    for backend in a.backends.split(","):
        if backend:
            deploy(backend, a.episodes, a.policy)


if __name__ == "__main__":
    main()
