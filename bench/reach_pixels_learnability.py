"""How well one frame (and the arm's own readings) predicts the reach teacher's action on
``Sim2Real/Arm3ReachPixels-v0``: the supervised problem a DAgger student (``--algo distill
--preset distill_reach_pixels``) has to solve, measured offline, then closed loop.

Frames come from rollouts of a privileged teacher (``--teacher``, the preset's ``reach_servo`` by
default, or ``reach_ik``) with Gaussian noise on its
action (σ drawn per episode in [0, ``--noise``]), so they cover the states a learning student
visits; each is labelled with the teacher's action. The student is the distilled run's own
policy (``AsymmetricActorCriticPolicy`` with the preset's extractor, heads and random shift),
fitted by the squared error of its mean as ``Distill`` fits it, on 85 % of the frames; the
other 15 % give the validation error. ``--rollouts N`` then runs the deterministic student for N
held-out episodes and prints its success at 2 cm: behaviour cloning's answer to "can this
observation locate the target well enough" (DAgger, which relabels the student's own states,
does at least as well). ``--aux-coef C`` adds ``distill``'s auxiliary head: the teacher's inputs
(the tool's offset to the target and the tool) regressed from the image features, weighted C.
``--no-stand`` renders the bare floating target: from one camera its
depth is then unobservable, which caps any pixel policy far below 90 %.

Prints JSON lines: ``reach_bc_val`` at every evaluation step (validation MSE, mean absolute
action error, fraction of frames whose action is within 0.1 of the teacher's on every joint;
with the head, the median error of its tool-to-target offset in mm),
then ``reach_bc_closed_loop_success`` with ``--rollouts``.

Run: ``nice -n 15 .venv/bin/python bench/reach_pixels_learnability.py [--image-size 64]
[--no-stand] [--no-proprio] [--frames 20000] [--steps 2000] [--rollouts 100]``.
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
os.environ.setdefault("OMP_NUM_THREADS", "1")

import gymnasium as gym
import numpy as np
import torch as th

import sim2real.envs as envs
from sim2real.evaluate.stats import wilson_interval
from sim2real.observation import PIXELS_KEY, PROPRIO_FIELDS, PROPRIO_KEY
from sim2real.train.asymmetric import AsymmetricActorCriticPolicy
from sim2real.train.augment import PRIVILEGED_KEY
from sim2real.train.config import EVAL_SEED_BASE
from sim2real.train.distill import AGREEMENT_TOL, get_teacher
from sim2real.train.extractors import resolve_policy_kwargs

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from support.load import emit

THRESHOLD_M = 0.02


def make_env(args: argparse.Namespace) -> gym.Env[Any, Any]:
    return envs.make(
        "reach-pixels",
        dr=args.dr,
        image_size=args.image_size,
        target_stand=args.stand,
        proprio=PROPRIO_FIELDS if args.proprio else (),
        success_threshold_m=THRESHOLD_M,
    )


def collect(args: argparse.Namespace) -> dict[str, np.ndarray]:
    """``args.frames`` channel-first frames (+ proprioception) and the teacher's action each."""
    env = make_env(args)
    teacher = get_teacher(args.teacher, env.unwrapped.decoder)  # type: ignore[attr-defined]
    rng = np.random.default_rng(args.seed)
    out: dict[str, list[np.ndarray]] = {PIXELS_KEY: [], PROPRIO_KEY: [], "label": [], "aux": []}
    episode = 0
    try:
        while len(out["label"]) < args.frames:
            obs, info = env.reset(seed=args.seed * 1_000_003 + episode)
            episode += 1
            sigma = rng.uniform(0.0, args.noise)
            done = False
            while not done:
                label = teacher.action(info["privileged_state"])
                frame = obs[PIXELS_KEY] if args.proprio else obs
                out[PIXELS_KEY].append(frame.transpose(2, 0, 1))
                if args.proprio:
                    out[PROPRIO_KEY].append(obs[PROPRIO_KEY])
                out["label"].append(label)
                out["aux"].append(teacher.inputs(info["privileged_state"]))
                action = np.clip(label + sigma * rng.standard_normal(label.shape), -1, 1)
                obs, _, term, trunc, info = env.step(action.astype(np.float32))
                done = term or trunc
    finally:
        env.close()
    return {k: np.stack(v[: args.frames]) for k, v in out.items() if v}


def student(args: argparse.Namespace, data: dict[str, np.ndarray]) -> AsymmetricActorCriticPolicy:
    spaces: dict[str, gym.spaces.Space[Any]] = {
        PIXELS_KEY: gym.spaces.Box(0, 255, data[PIXELS_KEY].shape[1:], np.uint8),
        PRIVILEGED_KEY: gym.spaces.Box(-np.inf, np.inf, (13,), np.float32),  # unused by the actor
    }
    if PROPRIO_KEY in data:
        spaces[PROPRIO_KEY] = gym.spaces.Box(-np.inf, np.inf, data[PROPRIO_KEY].shape[1:])
    pk = {"features_extractor": args.extractor, "net_arch": args.net_arch, "log_std_init": -2.3}
    kwargs = resolve_policy_kwargs(pk, args.shift_px, pixel_actor=True)
    actions = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)
    aux_dim = data["aux"].shape[1] if args.aux_coef else 0
    return AsymmetricActorCriticPolicy(
        gym.spaces.Dict(spaces), actions, lambda _: args.lr, aux_dim=aux_dim, **kwargs
    )


def closed_loop(policy: AsymmetricActorCriticPolicy, args: argparse.Namespace) -> list[float]:
    """Final distances of the deterministic student on held-out evaluation seeds."""
    env = make_env(args)
    final_m = []
    try:
        for j in range(args.rollouts):
            obs, _ = env.reset(seed=EVAL_SEED_BASE + j)
            done = False
            while not done:
                action, _ = policy.predict(obs, deterministic=True)
                obs, _, term, trunc, info = env.step(action)
                done = term or trunc
            final_m.append(float(info["distance_m"]))
    finally:
        env.close()
    return final_m


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--teacher", default="reach_servo")
    ap.add_argument("--image-size", type=int, default=64)
    ap.add_argument("--stand", action=argparse.BooleanOptionalAction, default=True)
    ap.add_argument("--proprio", action=argparse.BooleanOptionalAction, default=True)
    ap.add_argument("--extractor", default="keypoint_cnn")
    ap.add_argument(
        "--net-arch", type=lambda s: [int(n) for n in s.split(",") if n], default=[256, 256]
    )
    ap.add_argument("--shift-px", type=int, default=2)
    ap.add_argument("--frames", type=int, default=20_000)
    ap.add_argument("--noise", type=float, default=0.5, help="largest per-episode action noise σ")
    ap.add_argument("--steps", type=int, default=2_000)
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--eval-every", type=int, default=500)
    ap.add_argument("--dr", default="default")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rollouts", type=int, default=0, help="closed-loop held-out episodes")
    ap.add_argument("--aux-coef", type=float, default=0.0, help="auxiliary regression weight")
    args = ap.parse_args()
    th.set_num_threads(1)
    th.manual_seed(args.seed)
    t0 = time.perf_counter()
    data = collect(args)
    n_train = int(0.85 * len(data["label"]))
    common = {
        "teacher": args.teacher,
        "image_size": args.image_size,
        "stand": args.stand,
        "proprio": args.proprio,
        "extractor": args.extractor,
        "net_arch": args.net_arch,
        "frames": len(data["label"]),
        "dr": args.dr,
        "lr": args.lr,
        "aux_coef": args.aux_coef,
    }
    policy = student(args, data)
    tensors = {k: th.as_tensor(v) for k, v in data.items()}
    obs_keys = [k for k in (PIXELS_KEY, PROPRIO_KEY) if k in tensors]
    gen = th.Generator().manual_seed(args.seed)

    def heads(idx: th.Tensor) -> tuple[th.Tensor, th.Tensor | None]:
        """The student's mean action and its auxiliary prediction (None without the head)."""
        features = policy.actor_features({k: tensors[k][idx] for k in obs_keys})
        mean = policy.action_net(policy.mlp_extractor.forward_actor(features))
        return mean, None if policy.aux_head is None else policy.aux_head(features)

    def mean_action(idx: th.Tensor) -> th.Tensor:
        return heads(idx)[0]

    for step in range(1, args.steps + 1):
        policy.set_training_mode(True)
        idx = th.randint(0, n_train, (args.batch,), generator=gen)
        mean, aux = heads(idx)
        loss = th.nn.functional.mse_loss(mean, tensors["label"][idx])
        if aux is not None:
            loss = loss + args.aux_coef * th.nn.functional.mse_loss(aux, tensors["aux"][idx])
        policy.optimizer.zero_grad()
        loss.backward()
        th.nn.utils.clip_grad_norm_(policy.parameters(), 0.5)
        policy.optimizer.step()
        if step % args.eval_every == 0 or step == args.steps:
            policy.set_training_mode(False)
            val = th.arange(n_train, len(data["label"]))
            with th.no_grad():
                pred = th.cat([mean_action(v) for v in val.split(512)]).clamp(-1.0, 1.0)
                aux_mm = None
                if policy.aux_head is not None:  # the offset's error, in mm (inputs are in dm)
                    offset = th.cat([heads(v)[1][:, :3] for v in val.split(512)])  # type: ignore[index]
                    miss = (offset - tensors["aux"][val][:, :3]).norm(dim=1) * 100.0
                    aux_mm = round(float(miss.median()), 1)
            err = (pred - tensors["label"][val]).abs()
            emit(
                "reach_bc_val",
                round(float((err**2).mean()), 5),
                "mse",
                step=step,
                train_loss=round(loss.item(), 5),
                action_error=round(float(err.mean()), 4),
                agreement=round(float((err <= AGREEMENT_TOL).all(dim=1).float().mean()), 4),
                aux_offset_median_mm=aux_mm,
                wall_s=round(time.perf_counter() - t0, 1),
                **common,
            )
    if args.rollouts:
        d_mm = 1000.0 * np.array(closed_loop(policy, args))
        wins = int(np.sum(d_mm < 1000.0 * THRESHOLD_M))
        lo, hi = wilson_interval(wins, args.rollouts)
        emit(
            "reach_bc_closed_loop_success",
            round(wins / args.rollouts, 4),
            "fraction",
            episodes=args.rollouts,
            threshold_m=THRESHOLD_M,
            wilson95=[round(lo, 3), round(hi, 3)],
            median_final_mm=round(float(np.median(d_mm)), 2),
            wall_s=round(time.perf_counter() - t0, 1),
            **common,
        )


if __name__ == "__main__":
    main()
