"""Train a robosuite task from its shipped preset for a wall-clock budget, then evaluate held out.

The ecosystem issue's targets: DDPG and PPO on ``Sim2Real/RobosuiteReach-v0`` at >= 90 % held-out
success within 60 minutes each, DDPG and PPO on ``Sim2Real/RobosuiteLift-v0`` reported at 60
minutes, and SAC on Lift for 2 hours. Each run is exactly ``sim2real train --env ... --algo ...``
(the preset's ``max_wall_s`` replaced by ``--minutes``) then ``sim2real evaluate RUN --episodes N``
on fresh seeds. ``--resume`` continues an existing run directory from its newest checkpoint for
another ``--minutes`` (a 2-hour run in two sittings), and evaluates again.

Prints JSON lines: held-out success (the final step of each episode, Wilson 95 % interval), mean
return, env steps and steps/s, and when the *training* success (SB3's window of the last 100
episodes, with exploration) first reached 50 % and 90 %. Writes the training curve (success
against wall minutes, all segments) as ``curve.png`` and ``curve.jsonl`` in the run directory.

Run: ``MUJOCO_GL=egl .venv/bin/python bench/robosuite_train.py --env reach --algo ppo``
(``--minutes 5`` for a quick look).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from support.load import emit

from s2r_common.atomic import atomic_write_text
from sim2real.evaluate import EvalTarget, evaluate
from sim2real.train import resolve_config, resume, train

ENVS = {"reach": "Sim2Real/RobosuiteReach-v0", "lift": "Sim2Real/RobosuiteLift-v0"}
SEGMENTS = "segments.json"  # per sitting: minutes, steps at its end, held-out figures


def curve(run: Path, segments: list[dict[str, Any]]) -> list[dict[str, float]]:
    """Training success against wall minutes over every sitting, from the run's metrics.jsonl.

    SB3 restarts ``time_elapsed`` at each sitting, so a point's minutes are its sitting's elapsed
    time plus the wall time of the sittings before it (a sitting is the rows after the previous
    sitting's last step)."""
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines() if line]
    points: list[dict[str, float]] = []
    offset_min, start_steps = 0.0, 0
    for seg in segments:
        for row in rows:
            steps = float(row.get("timesteps", 0))
            if start_steps < steps <= seg["steps"] and "rollout/success_rate" in row:
                minutes = offset_min + float(row.get("time/time_elapsed", 0.0)) / 60.0
                points.append(
                    {
                        "minutes": round(minutes, 2),
                        "steps": steps,
                        "train_success": float(row["rollout/success_rate"]),
                    }
                )
        offset_min += seg["minutes"]
        start_steps = seg["steps"]
    return points


def first_reaching(points: list[dict[str, float]], level: float) -> dict[str, float] | None:
    return next((p for p in points if p["train_success"] >= level), None)


def plot(
    points: list[dict[str, float]], segments: list[dict[str, Any]], title: str, path: Path
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.0, 3.5))
    ax.plot(
        [p["minutes"] for p in points],
        [p["train_success"] for p in points],
        label="training success (last 100 episodes, with exploration)",
    )
    done = 0.0
    for seg in segments:
        done += seg["minutes"]
        lo, hi = seg["wilson95"]
        ax.errorbar(
            [done],
            [seg["success_rate"]],
            yerr=[[seg["success_rate"] - lo], [hi - seg["success_rate"]]],
            fmt="o",
            color="k",
            capsize=3,
        )
    ax.plot([], [], "ok", label="held-out success (Wilson 95 %)")
    ax.set(xlabel="wall minutes", ylabel="success", ylim=(-0.02, 1.02), title=title)
    ax.legend(loc="lower right", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", choices=sorted(ENVS), default="reach")
    parser.add_argument("--algo", default="ppo", help="ppo, ddpg, sac, td3 (a shipped preset)")
    parser.add_argument("--minutes", type=float, default=60.0, help="this sitting's budget")
    parser.add_argument("--resume", action="store_true", help="continue the run for --minutes")
    parser.add_argument("--robot", default="Panda")
    parser.add_argument("--dr", default="default", help="DR preset for training and evaluation")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--eval-episodes", type=int, default=200)
    parser.add_argument("--results-dir", type=Path, default=Path(".cache/bench/robosuite_train"))
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="preset override, as sim2real train's (vec_env=dummy: one core per run)",
    )
    args = parser.parse_args()

    env_id = ENVS[args.env]
    run = args.results_dir / f"{args.env}-{args.algo}-{args.robot.lower()}-s{args.seed}"
    seg_path = run / SEGMENTS
    load = round(os.getloadavg()[0], 2)
    t0 = time.perf_counter()
    if args.resume:
        segments = json.loads(seg_path.read_text())
        result = resume(run, progress=False, max_wall_s=60.0 * args.minutes)
    else:
        shutil.rmtree(run, ignore_errors=True)
        segments = []
        cfg = resolve_config(
            env_id,
            args.algo,
            run,
            dr=args.dr,
            seed=args.seed,
            progress=False,
            max_wall_s=60.0 * args.minutes,
            overrides=[f"env_kwargs.robot={args.robot}", *args.set],
        )
        result = train(cfg)
    train_min = (time.perf_counter() - t0) / 60.0
    ev = evaluate(EvalTarget.load(run), args.eval_episodes, dr=args.dr)
    segments.append(
        {
            "minutes": round(train_min, 2),
            "steps": result.steps_done,
            "success_rate": ev["success_rate"],
            "wilson95": [round(x, 3) for x in ev["success_rate_wilson95"]],
            "mean_return": round(float(ev["mean_return"]), 2),
            "date": dt.date.today().isoformat(),
            "load_1min": [load, round(os.getloadavg()[0], 2)],
        }
    )
    atomic_write_text(seg_path, json.dumps(segments, indent=1))  # --resume reads it back
    points = curve(run, segments)
    (run / "curve.jsonl").write_text("".join(json.dumps(p) + "\n" for p in points))
    total_min = sum(s["minutes"] for s in segments)
    title = f"{args.algo.upper()} on {env_id.split('/')[1]} ({args.robot}, DR {args.dr})"
    plot(points, segments, title, run / "curve.png")

    info = {
        "env": env_id,
        "algo": args.algo,
        "robot": args.robot,
        "dr": args.dr,
        "seed": args.seed,
        "sittings": len(segments),
        "minutes_total": round(total_min, 2),
        "env_steps": result.steps_done,
        **{k: segments[-1][k] for k in ("date", "load_1min")},
    }
    emit(
        f"robosuite_{args.env}_{args.algo}_success_rate",
        ev["success_rate"],
        "fraction",
        episodes=ev["episodes"],
        wilson95=segments[-1]["wilson95"],
        **info,
    )
    emit(
        f"robosuite_{args.env}_{args.algo}_mean_return",
        segments[-1]["mean_return"],
        "reward/episode",
    )
    emit(
        f"robosuite_{args.env}_{args.algo}_steps_per_s",
        round(result.steps_per_s, 1),
        "steps/s",
        includes="env + updates, this sitting",
    )
    for level in (0.5, 0.9):
        hit = first_reaching(points, level)
        emit(
            f"robosuite_{args.env}_{args.algo}_minutes_to_train_success_{int(level * 100)}",
            hit["minutes"] if hit else None,
            "min",
            steps=hit["steps"] if hit else None,
        )
    emit(f"robosuite_{args.env}_{args.algo}_curve", str(run / "curve.png"), "path")


if __name__ == "__main__":
    main()
