"""How well one 48x48 frame predicts the privileged teacher's action on KukaGraspFast: the
supervised problem a DAgger student (``--algo distill``) has to solve, measured offline.

Frames come from rollouts that follow the scripted teacher (``kuka_grasp.privileged_teacher_action``)
half the time and a uniformly random action otherwise, so they cover the states a learning student
visits. Each is labelled with the teacher's action. A named CNN extractor plus a linear head is
trained by cross-entropy on 85% of them, and its accuracy on the held-out 15% is printed during
training. The majority class is printed beside it, since that is what a student that ignores
the image scores.

Prints JSON lines: ``teacher_label_majority_fraction``, then
``teacher_label_val_accuracy`` at every evaluation step (``extractor``, ``step``, ``train_loss``).

Run: ``nice -n 10 .venv/bin/python bench/kuka_teacher_learnability.py [--extractor keypoint_cnn]
[--frames 12000] [--steps 1500] [--lr 3e-4]``.
"""

from __future__ import annotations

import argparse
import json
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
os.environ.setdefault("LP_NUM_THREADS", "0")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import gymnasium as gym
import numpy as np
import torch as th

import sim2real.envs as envs
from sim2real.envs import kuka_grasp as kg
from sim2real.train.extractors import FEATURE_EXTRACTORS, get_extractor


def emit(metric: str, value: float, **extra: object) -> None:
    print(json.dumps({"metric": metric, "value": round(value, 4), **extra}), flush=True)


def collect(n: int, dr: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3, 48, 48) uint8 frames and the teacher's action for each."""
    env = envs.make("Sim2Real/KukaGraspFast-v0", dr=dr)
    rng = np.random.default_rng(seed)
    frames: list[np.ndarray] = []
    labels: list[int] = []
    episode = 0
    try:
        while len(frames) < n:
            obs, info = env.reset(seed=seed * 1_000_003 + episode)
            episode += 1
            done = False
            while not done:
                label = kg.privileged_teacher_action(info[kg.PRIVILEGED_INFO_KEY])
                frames.append(obs.transpose(2, 0, 1))
                labels.append(label)
                action = label if rng.random() < 0.5 else int(rng.integers(7))
                obs, _, done, _, info = env.step(action)
    finally:
        env.close()
    return np.stack(frames[:n]), np.array(labels[:n], dtype=np.int64)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--extractor", default="nature_cnn", choices=sorted(FEATURE_EXTRACTORS))
    ap.add_argument("--frames", type=int, default=12_000)
    ap.add_argument("--steps", type=int, default=1_500)
    ap.add_argument("--lr", type=float, default=3e-4)
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--eval-every", type=int, default=250)
    ap.add_argument("--dr", default="default")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    th.set_num_threads(1)
    th.manual_seed(args.seed)
    t0 = time.perf_counter()
    x, y = collect(args.frames, args.dr, args.seed)
    n_train = int(0.85 * len(x))
    common = {"extractor": args.extractor, "frames": len(x), "dr": args.dr, "lr": args.lr}
    counts = np.bincount(y[n_train:], minlength=7)
    emit("teacher_label_majority_fraction", float(counts.max() / counts.sum()), **common)
    space = gym.spaces.Box(0, 255, x.shape[1:], np.uint8)
    cnn = get_extractor(args.extractor)(space)
    model = th.nn.Sequential(cnn, th.nn.Linear(cnn.features_dim, 7))
    opt = th.optim.Adam(model.parameters(), lr=args.lr)
    xt, yt = th.as_tensor(x), th.as_tensor(y)
    gen = th.Generator().manual_seed(args.seed)
    for step in range(1, args.steps + 1):
        idx = th.randint(0, n_train, (args.batch,), generator=gen)
        loss = th.nn.functional.cross_entropy(model(xt[idx].float() / 255), yt[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step % args.eval_every == 0 or step == args.steps:
            with th.no_grad():
                pred = model(xt[n_train:].float() / 255).argmax(dim=1)
            acc = float((pred == yt[n_train:]).float().mean())
            emit(
                "teacher_label_val_accuracy",
                acc,
                step=step,
                train_loss=round(float(loss), 4),
                wall_s=round(time.perf_counter() - t0, 1),
                **common,
            )


if __name__ == "__main__":
    main()
