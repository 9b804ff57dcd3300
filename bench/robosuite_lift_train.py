"""Train robosuite Lift (Panda) from a shipped DR preset for a wall-clock budget, then evaluate.

The issue's target is a 60-minute run on this CPU (``--minutes 60``); shorter runs report the same
figures plus the measured training speed, so the step count a longer run reaches is known. Prints
JSON lines: held-out success rate (final step of each episode, Wilson 95% interval), mean return,
the training-time success of the last episodes, env steps and steps/s.

Run: ``MUJOCO_GL=egl nice -n 10 .venv/bin/python bench/robosuite_lift_train.py --minutes 10``
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import tempfile
import time
from collections import deque
from pathlib import Path
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import gymnasium as gym
import numpy as np

import sim2real.envs  # registers the ids

ENV_ID = "Sim2Real/RobosuiteLift-v0"
EVAL_SEED_OFFSET = 1_000_000  # held-out episodes never share a seed with training


def wilson95(successes: int, n: int) -> tuple[float, float]:
    if n == 0:
        return 0.0, 1.0
    z, p = 1.959964, successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def evaluate(model: Any, env: gym.Env, episodes: int) -> tuple[int, list[float], list[float]]:
    """Deterministic policy; an episode succeeds if its final step succeeds (cube lifted, or the
    grip site within 1 cm). Returns (successes, returns, final ``distance_m``)."""
    successes, returns, finals = 0, [], []
    for k in range(episodes):
        obs, _ = env.reset(seed=EVAL_SEED_OFFSET + k)
        ret, trunc = 0.0, False
        info: dict[str, Any] = {}
        while not trunc:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, term, trunc, info = env.step(action)
            ret += float(reward)
            trunc = trunc or term
        successes += int(info["is_success"])
        returns.append(ret)
        finals.append(float(info["distance_m"]))
    return successes, returns, finals


def emit(metric: str, value: float, unit: str, **extra: object) -> None:
    print(
        json.dumps({"metric": metric, "value": round(value, 4), "unit": unit, **extra}), flush=True
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="training wall-clock budget")
    parser.add_argument("--env", default=ENV_ID, help="id or short name (reach: a quick check)")
    parser.add_argument("--robot", default="Panda")
    parser.add_argument("--dr", default="default", help="DR preset for training and evaluation")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--eval-episodes", type=int, default=50)
    parser.add_argument("--out", type=Path, default=None, help="save the policy here (.zip)")
    args = parser.parse_args()

    import torch
    from stable_baselines3 import SAC
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.monitor import Monitor

    torch.set_num_threads(1)
    budget_s = args.minutes * 60.0

    class Budget(BaseCallback):
        """Stops at the wall-clock budget; logs training-episode success as it goes."""

        def __init__(self) -> None:
            super().__init__()
            self.t0 = time.perf_counter()
            self.recent: deque[bool] = deque(maxlen=50)
            self.episodes = 0
            self.next_log_s = 60.0

        def _on_step(self) -> bool:
            for info, done in zip(self.locals["infos"], self.locals["dones"], strict=True):
                if done:
                    self.episodes += 1
                    self.recent.append(bool(info["is_success"]))
            elapsed = time.perf_counter() - self.t0
            if elapsed >= self.next_log_s:
                self.next_log_s += 60.0
                rate = sum(self.recent) / max(1, len(self.recent))
                print(
                    json.dumps(
                        {
                            "progress_min": round(elapsed / 60, 1),
                            "env_steps": self.num_timesteps,
                            "episodes": self.episodes,
                            "train_success_last50": round(rate, 3),
                        }
                    ),
                    flush=True,
                )
            return elapsed < budget_s

    env_id = sim2real.envs.resolve_env_id(args.env)
    name = env_id.split("/")[-1].removesuffix("-v0").replace("Robosuite", "robosuite_").lower()
    env = Monitor(gym.make(env_id, robot=args.robot, dr=args.dr), info_keywords=("is_success",))
    model = SAC(
        "MlpPolicy",
        env,
        learning_rate=3e-4,
        buffer_size=300_000,
        learning_starts=2_000,
        batch_size=256,
        tau=0.005,
        gamma=0.98,  # 50- or 100-step episodes: an effective horizon of about 50 steps
        train_freq=1,
        gradient_steps=1,
        policy_kwargs={"net_arch": [256, 256]},
        seed=args.seed,
        device="cpu",
    )
    budget = Budget()
    t0 = time.perf_counter()
    model.learn(total_timesteps=10**9, callback=budget)
    train_s = time.perf_counter() - t0
    steps = model.num_timesteps
    env.close()

    if args.out is not None:  # atomic: temp file in the same folder, then rename
        args.out.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(suffix=".zip", dir=args.out.parent)
        os.close(fd)
        model.save(tmp)
        os.replace(tmp, args.out)

    eval_env = gym.make(env_id, robot=args.robot, dr=args.dr)
    base: Any = eval_env.unwrapped
    max_steps = float(base.max_episode_steps)
    t1 = time.perf_counter()
    successes, returns, finals = evaluate(model, eval_env, args.eval_episodes)
    eval_s = time.perf_counter() - t1
    eval_env.close()

    run = {
        "env": env_id,
        "algo": "SAC",
        "robot": args.robot,
        "dr": args.dr,
        "seed": args.seed,
        "minutes": round(train_s / 60, 2),
        "env_steps": steps,
        "date": dt.date.today().isoformat(),
        "load_1min": round(os.getloadavg()[0], 2),
    }
    n = args.eval_episodes
    lo, hi = wilson95(successes, n)
    emit(
        f"{name}_success_rate",
        successes / n,
        "fraction",
        episodes=n,
        wilson95=[round(lo, 3), round(hi, 3)],
        **run,
    )
    emit(
        f"{name}_mean_return",
        float(np.mean(returns)),
        "reward/episode",
        episodes=n,
        max_possible=max_steps,
    )
    emit(
        f"{name}_median_final_distance_m",
        float(np.median(finals)),
        "m",
        episodes=n,
        note="reach: grip site to target; lift: cube centre below the success height",
    )
    recent = list(budget.recent)
    emit(
        f"{name}_train_success_last50",
        sum(recent) / max(1, len(recent)),
        "fraction",
        episodes=len(recent),
    )
    emit(
        f"{name}_train_steps_per_s",
        steps / train_s,
        "steps/s",
        includes="env + SAC updates, 1 torch thread",
    )
    emit(
        f"{name}_steps_in_60_min",
        steps / train_s * 3600.0,
        "steps",
        note="at this run's speed",
    )
    emit(f"{name}_eval_s", eval_s, "s")


if __name__ == "__main__":
    main()
