"""How well a shipped state policy teaches on the pixel pick (``distill``'s ``pick_ppo`` or
``pick_ddpg``, ``state_teacher.StatePolicyTeacher``): the ceiling a distilled pixel student of
``Sim2Real/Arm3PickPixels-v0`` can approach.

The teacher drives the real pixel env (frames rendered at the ``distill_pick_pixels`` preset's
64 px, as in training) from ``info["privileged_state"]`` alone, on held-out evaluation seeds,
with the env kwargs the policy was trained with (its card's ``safety_filter``). Success is the
env's, on the final step. Beside it the same policy runs on the state env with the same seeds:
the privileged tail is that env's observation bit for bit, so the two must agree episode by
episode (``same_outcome``); a gap would be an observation mismatch, not noise.

Prints one JSON line per teacher and DR preset: ``pick_teacher_success`` (value = success rate)
with its Wilson interval, the state env's rate, the episodes with the same outcome, and pixel
env steps per CPU-second.

Run: ``nice -n 15 .venv/bin/python bench/pick_teacher.py [--episodes 100] [--dr default]
[--teacher pick_ppo,pick_ddpg]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
os.environ.setdefault("LP_NUM_THREADS", "0")

import sim2real.envs as envs
from sim2real.evaluate.stats import wilson_interval
from sim2real.train.config import EVAL_SEED_BASE
from sim2real.train.distill import get_teacher
from sim2real.train.state_teacher import shipped_policy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from support.load import emit

POLICY = {"pick_ppo": "pick-ppo", "pick_ddpg": "pick-ddpg"}  # teacher -> its shipped policy


def _episodes(env: Any, act: Any, episodes: int, key: str | None) -> tuple[list[bool], int]:
    wins, steps = [], 0
    try:
        for j in range(episodes):
            obs, info = env.reset(seed=EVAL_SEED_BASE + j)
            done = False
            while not done:
                obs, _, term, trunc, info = env.step(act(obs if key is None else info[key]))
                done, steps = term or trunc, steps + 1
            wins.append(bool(info["is_success"]))
    finally:
        env.close()
    return wins, steps


def run(name: str, dr: str, episodes: int, image_size: int) -> None:
    kwargs = dict(shipped_policy(POLICY[name]).meta.env_kwargs)
    env = envs.make("pick-pixels", dr=dr, image_size=image_size, **kwargs)
    teacher = get_teacher(name, env.unwrapped.decoder)  # type: ignore[attr-defined]
    assert teacher.check_env is not None
    teacher.check_env(env.spec.kwargs if env.spec is not None else {})
    t0 = time.process_time()
    wins, steps = _episodes(env, teacher.action, episodes, "privileged_state")
    rate = steps / max(time.process_time() - t0, 1e-9)
    state_env = envs.make("pick", dr=dr, **kwargs)
    state_wins, _ = _episodes(state_env, shipped_policy(POLICY[name]), episodes, None)
    lo, hi = wilson_interval(sum(wins), episodes)
    emit(
        "pick_teacher_success",
        round(sum(wins) / episodes, 4),
        "fraction",
        teacher=name,
        dr=dr,
        episodes=episodes,
        env_kwargs=kwargs,
        image_size=image_size,
        wilson95=[round(lo, 4), round(hi, 4)],
        state_env_success=round(sum(state_wins) / episodes, 4),
        same_outcome=sum(a == b for a, b in zip(wins, state_wins, strict=True)),
        steps_per_cpu_s=round(rate, 1),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--dr", default="default", help="comma-separated DR presets")
    ap.add_argument("--image-size", type=int, default=64)
    ap.add_argument("--teacher", default="pick_ppo", help="comma-separated teachers")
    args = ap.parse_args()
    for name in args.teacher.split(","):
        for dr in args.dr.split(","):
            run(name, dr, args.episodes, args.image_size)


if __name__ == "__main__":
    main()
