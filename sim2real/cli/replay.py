"""``sim2real replay DIR``: read a recorded LeRobot dataset back (summary, or one episode).

Without ``--episode`` it prints what the dataset holds (episodes, frames, features, fps, task,
success). ``--episode N`` prints that episode frame by frame (state, action, estimates, step
flags) and checks that every camera decodes to as many frames as the episode has; ``--step``
waits for Enter between frames on a terminal (``q`` stops).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

import numpy as np

INDEX_COLUMNS = ("timestamp", "frame_index", "episode_index", "index", "task_index")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dataset", help="dataset folder (meta/info.json inside)")
    parser.add_argument("--episode", type=int, help="print this episode frame by frame")
    parser.add_argument("--step", action="store_true", help="wait for Enter between frames")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _fmt(v: Any) -> str:
    a = np.asarray(v)
    if a.dtype == bool:
        return "1" if bool(a.reshape(-1)[0]) else "0"
    if a.ndim == 0:
        return f"{float(a):.4g}"
    return "[" + " ".join(f"{x:+.3f}" for x in a.astype(float)) + "]"


def run(args: argparse.Namespace) -> int:
    from sim2real.datasets import LeRobotDataset

    ds = LeRobotDataset.open(args.dataset)
    if args.episode is None:
        summary = ds.summary()
        summary["episode_success"] = [e.success for e in ds.episodes]
        if args.json:
            print(json.dumps(summary, allow_nan=True))
            return 0
        for key in ("dataset", "format", "robot_type", "episodes", "frames", "fps"):
            print(f"{key:14s} {summary[key]}")
        print(f"{'tasks':14s} {'; '.join(summary['tasks'])}")
        rate = summary["success_rate"]
        print(f"{'success':14s} " + ("n/a" if math.isnan(rate) else f"{rate:.0%}"))
        print("features")
        for name, kind in summary["features"].items():
            print(f"  {name:34s} {kind}")
        return 0
    return _episode(ds, args)


def _episode(ds: Any, args: argparse.Namespace) -> int:
    from sim2real.datasets import DatasetError

    ep = ds.episodes[args.episode] if 0 <= args.episode < len(ds.episodes) else None
    if ep is None:
        raise DatasetError(f"episode {args.episode} not in [0, {len(ds.episodes) - 1}]")
    frames = ds.episode_frames(args.episode)
    decoded = {cam: sum(1 for _ in ds.video_frames(args.episode, cam)) for cam in ds.cameras}
    shown = [k for k in frames if k not in INDEX_COLUMNS]
    if args.json:
        print(
            json.dumps(
                {
                    "episode": ep.index,
                    "length": ep.length,
                    "task": ep.task,
                    "success": ep.success,
                    "video_frames": decoded,
                    "frames": {k: np.asarray(frames[k]).tolist() for k in shown},
                }
            )
        )
        return 0
    print(f"episode {ep.index}: {ep.length} frames, task {ep.task!r}, success {ep.success}")
    for cam, n in decoded.items():
        print(f"  {cam}: {n} video frames decoded")
    interactive = args.step and sys.stdin.isatty()
    for i in range(ep.length):
        t = float(frames["timestamp"][i])
        cols = "  ".join(f"{k.removeprefix('observation.')}={_fmt(frames[k][i])}" for k in shown)
        print(f"{i:4d} t={t:6.2f}s  {cols}")
        if interactive and input("").strip().lower() == "q":
            break
    return 0
