"""How well one 48x48 frame predicts the privileged teacher's action on KukaGraspFast: the
supervised problem a DAgger student (``--algo distill``) has to solve, measured offline.

Frames come from rollouts that follow the scripted teacher (``kuka_grasp.privileged_teacher_action``)
half the time and a uniformly random action otherwise, so they cover the states a learning student
visits. Each is labelled with the teacher's action. A named CNN extractor plus a linear head is
trained by cross-entropy on 85% of them, and its accuracy on the held-out 15% is printed during
training. The majority class is printed beside it, since that is what a student that ignores
the image scores. ``--aux-coef C`` adds an auxiliary regression head on the same features: the
nearest object's offset from the gripper target, the target's x, y and the episode's progress
(the teacher's inputs, from the privileged state), weighted C against the cross-entropy; only the
action head acts. ``--rollouts N`` then runs the trained classifier closed-loop (greedy action,
the frame alone) for N held-out episodes and prints its grasp success with a Wilson interval:
behaviour cloning's answer to "how far does imitation of this teacher go from one frame".

Prints JSON lines: ``teacher_label_majority_fraction``, then
``teacher_label_val_accuracy`` at every evaluation step (``extractor``, ``step``, ``train_loss``),
then ``bc_closed_loop_success`` with ``--rollouts``.

Run: ``nice -n 10 .venv/bin/python bench/kuka_teacher_learnability.py [--extractor keypoint_cnn]
[--frames 12000] [--steps 1500] [--lr 3e-4] [--aux-coef 1] [--rollouts 200]``.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
os.environ.setdefault("LP_NUM_THREADS", "0")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import gymnasium as gym
import numpy as np
import torch as th
from support.load import emit_row

import sim2real.envs as envs
from sim2real.envs import kuka_grasp as kg
from sim2real.evaluate.stats import wilson_interval
from sim2real.train.distill import get_teacher
from sim2real.train.extractors import FEATURE_EXTRACTORS, get_extractor

TEACHER = get_teacher("kuka_scripted")  # its inputs are the auxiliary target, as in distill
HELD_OUT_SEED = 900_000_000  # far from the collection seeds


def emit(metric: str, value: float, **extra: object) -> None:
    emit_row({"metric": metric, "value": round(value, 4), **extra})


def collect(
    n: int, dr: str, seed: int, teacher_prob: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, 3, 48, 48) uint8 frames, the teacher's action and the auxiliary target for each."""
    env = envs.make("Sim2Real/KukaGraspFast-v0", dr=dr)
    rng = np.random.default_rng(seed)
    frames: list[np.ndarray] = []
    labels: list[int] = []
    aux: list[np.ndarray] = []
    episode = 0
    try:
        while len(frames) < n:
            obs, info = env.reset(seed=seed * 1_000_003 + episode)
            episode += 1
            done = False
            while not done:
                privileged = info[kg.PRIVILEGED_INFO_KEY]
                label = TEACHER.action(privileged)
                frames.append(obs.transpose(2, 0, 1))
                labels.append(label)
                aux.append(TEACHER.inputs(privileged))
                action = label if rng.random() < teacher_prob else int(rng.integers(7))
                obs, _, done, _, info = env.step(action)
    finally:
        env.close()
    return np.stack(frames[:n]), np.array(labels[:n], dtype=np.int64), np.stack(aux[:n])


def closed_loop(model: th.nn.Module, episodes: int, dr: str) -> float:
    """Grasp success of the greedy classifier on held-out episode seeds."""
    env = envs.make("Sim2Real/KukaGraspFast-v0", dr=dr)
    wins = 0
    try:
        for j in range(episodes):
            obs, info = env.reset(seed=HELD_OUT_SEED + j)
            done = False
            while not done:
                with th.no_grad():
                    x = th.as_tensor(obs.transpose(2, 0, 1)[None]).float() / 255
                    action = int(model(x)[0, :7].argmax())
                obs, _, done, _, info = env.step(action)
            wins += bool(info["is_success"])
    finally:
        env.close()
    return wins / episodes


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
    ap.add_argument("--teacher-prob", type=float, default=0.5, help="else a random action")
    ap.add_argument("--aux-coef", type=float, default=0.0, help="auxiliary regression weight")
    ap.add_argument("--rollouts", type=int, default=0, help="closed-loop held-out episodes")
    args = ap.parse_args()
    th.set_num_threads(1)
    th.manual_seed(args.seed)
    t0 = time.perf_counter()
    x, y, z = collect(args.frames, args.dr, args.seed, args.teacher_prob)
    n_train = int(0.85 * len(x))
    common = {
        "extractor": args.extractor,
        "frames": len(x),
        "dr": args.dr,
        "lr": args.lr,
        "aux_coef": args.aux_coef,
        "teacher_prob": args.teacher_prob,
    }
    counts = np.bincount(y[n_train:], minlength=7)
    emit("teacher_label_majority_fraction", float(counts.max() / counts.sum()), **common)
    space = gym.spaces.Box(0, 255, x.shape[1:], np.uint8)
    cnn = get_extractor(args.extractor)(space)
    # One linear layer gives the 7 action logits and the auxiliary regression side by side.
    model = th.nn.Sequential(cnn, th.nn.Linear(cnn.features_dim, 7 + TEACHER.n_inputs))
    opt = th.optim.Adam(model.parameters(), lr=args.lr)
    xt, yt, zt = th.as_tensor(x), th.as_tensor(y), th.as_tensor(z)
    gen = th.Generator().manual_seed(args.seed)
    for step in range(1, args.steps + 1):
        idx = th.randint(0, n_train, (args.batch,), generator=gen)
        out = model(xt[idx].float() / 255)
        loss = th.nn.functional.cross_entropy(out[:, :7], yt[idx])
        if args.aux_coef:
            loss = loss + args.aux_coef * th.nn.functional.mse_loss(out[:, 7:], zt[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step % args.eval_every == 0 or step == args.steps:
            with th.no_grad():
                pred = model(xt[n_train:].float() / 255)[:, :7].argmax(dim=1)
            acc = float((pred == yt[n_train:]).float().mean())
            emit(
                "teacher_label_val_accuracy",
                acc,
                step=step,
                train_loss=round(loss.item(), 4),
                wall_s=round(time.perf_counter() - t0, 1),
                **common,
            )
    if args.rollouts:
        rate = closed_loop(model.eval(), args.rollouts, args.dr)
        lo, hi = wilson_interval(round(rate * args.rollouts), args.rollouts)
        emit(
            "bc_closed_loop_success",
            rate,
            episodes=args.rollouts,
            wilson95=[round(lo, 3), round(hi, 3)],
            wall_s=round(time.perf_counter() - t0, 1),
            **common,
        )


if __name__ == "__main__":
    main()
