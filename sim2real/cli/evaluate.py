"""``sim2real evaluate RUN``: held-out success, a video, the viewer, the transfer-gap sweep, or a
LeRobot dataset of the rollouts."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from sim2real.errors import ConfigError

RENDER_MODES: tuple[str, ...] = ("none", "human")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="run dir, exported .onnx or .npz policy, or a shipped name")
    parser.add_argument("--episodes", type=int, default=200, help="held-out episodes (200)")
    parser.add_argument("--dr", help="DR preset to evaluate under (default: the training one)")
    parser.add_argument("--seed-offset", type=int, default=0, help="first held-out seed offset")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--video", metavar="FILE.mp4", help="record rollouts from the camera")
    parser.add_argument("--video-episodes", type=int, default=3, help="episodes in the video")
    parser.add_argument("--camera", default="cam_left", help="rig camera for --video")
    parser.add_argument("--render", default="none", help="'human' opens the MuJoCo viewer")
    parser.add_argument("--sweep", action="store_true", help="transfer-gap grid: CSV + heatmap")
    parser.add_argument(
        "--sweep-axis",
        action="append",
        default=[],
        metavar="NAME[=V1,V2,..]",
        help="a swept DR key (repeat, up to 3; default latency_steps, actuator_gain, obs_noise_px)",
    )
    parser.add_argument(
        "--sweep-episodes", type=int, default=30, help="held-out episodes per sweep cell (30)"
    )
    parser.add_argument("--out", help="folder for sweep outputs (default RUN/eval/)")
    parser.add_argument(
        "--record-dataset",
        metavar="DIR",
        help="write the --episodes rollouts as a LeRobot v3.0 dataset (state, action, estimates, "
        "both cameras as video, task, success)",
    )
    parser.add_argument(
        "--dataset-image-size",
        default="320x240",
        metavar="WxH",
        help="camera size for --record-dataset (320x240); 'none' records no video",
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="replace an existing --record-dataset DIR"
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _print(summary: dict[str, Any], as_json: bool) -> None:
    if as_json:
        print(json.dumps(summary))
        return
    for k, v in summary.items():
        if isinstance(v, float):
            v = f"{v:.4g}"
        print(f"{k:26s} {v}")


def run(args: argparse.Namespace) -> int:
    import torch

    from sim2real.errors import UnknownNameError
    from sim2real.evaluate import EvalTarget, evaluate

    torch.set_num_threads(1)
    if args.render not in RENDER_MODES:
        raise UnknownNameError("render mode", args.render, RENDER_MODES)
    modes = [
        m
        for m, on in (
            ("--sweep", args.sweep),
            ("--video", args.video),
            ("--render human", args.render == "human"),
            ("--record-dataset", args.record_dataset),
        )
        if on
    ]
    if len(modes) > 1:
        raise ConfigError(f"conflicting flags: {' and '.join(modes)}; choose one")
    if args.sweep_axis and not args.sweep:
        raise ConfigError("conflicting flags: --sweep-axis needs --sweep")
    target = EvalTarget.load(args.run)
    progress = not (args.json or args.no_progress)
    if args.sweep:
        return _sweep(args, target)
    if args.record_dataset:
        return _record(args, target, progress)
    if args.video or args.render == "human":
        from sim2real.evaluate.video import record_video, view_human

        dr = target.dr(args.dr)
        seeds = target.held_out_seeds(args.video_episodes, args.seed_offset)
        if args.video:
            path, result = record_video(target, args.video, dr, seeds, camera=args.camera)
            summary = {"video": str(path), "dr": dr.name, **result.summary()}
        else:
            summary = {"viewer": "closed", "dr": dr.name, **view_human(target, dr, seeds).summary()}
        _print(summary, args.json)
        return 0
    _print(evaluate(target, args.episodes, args.dr, args.seed_offset, progress=progress), args.json)
    return 0


def _record(args: argparse.Namespace, target: Any, progress: bool) -> int:
    from sim2real.evaluate.dataset import parse_image_size, record_dataset

    size = None if args.dataset_image_size == "none" else parse_image_size(args.dataset_image_size)
    dr = target.dr(args.dr)
    seeds = target.held_out_seeds(args.episodes, args.seed_offset)
    path, result, frames = record_dataset(
        target, args.record_dataset, dr, seeds, size, progress, overwrite=args.overwrite
    )
    summary = {"dataset": str(path), "frames": frames, "dr": dr.name, **result.summary()}
    _print(summary, args.json)
    return 0


def _sweep(args: argparse.Namespace, target: Any) -> int:
    from sim2real.evaluate.sweep import parse_axes, plot_heatmap, run_sweep, write_csv

    grid = parse_axes(args.sweep_axis)
    run = Path(args.run)
    if not run.exists():  # a shipped policy's name: results beside the user's runs
        run = Path("runs") / f"{args.run}.shipped"
    out = Path(args.out) if args.out else (run / "eval" if run.is_dir() else run.with_suffix(""))
    base = target.dr(args.dr)
    rows = run_sweep(
        target,
        grid,
        args.sweep_episodes,
        base_dr=args.dr,
        seed_offset=args.seed_offset,
        progress=not (args.json or args.no_progress),
    )
    stem = f"sweep-{base.name}"
    csv_path = write_csv(rows, out / f"{stem}.csv")
    title = f"{target.env_id} {target.policy.meta.algo}: success on held-out perturbations"
    png_path = plot_heatmap(rows, grid, out / f"{stem}.png", title)
    best = max(rows, key=lambda r: r["success_rate"])
    worst = min(rows, key=lambda r: r["success_rate"])
    summary = {
        "csv": str(csv_path),
        "heatmap": str(png_path),
        "cells": len(rows),
        "episodes_per_cell": args.sweep_episodes,
        "base_dr": base.name,
        "best_cell": best,
        "worst_cell": worst,
    }
    _print(summary, args.json)
    return 0
