"""``sim2real compare``: train every (algo, seed) under the same conditions and report."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import threading
from collections.abc import Iterator
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--env", default="Sim2Real/Arm3Reach-v0", help="env id or short name")
    parser.add_argument("--algos", default="a2c,dqn,ppo", help="comma-separated algorithms")
    parser.add_argument("--seeds", type=int, default=3, help="seeds per algorithm (0..N-1)")
    parser.add_argument("--steps", type=int, default=100_000, help="env steps per run")
    parser.add_argument("--dr", default="default", help="DR preset for training and evaluation")
    parser.add_argument("--out", required=False, help="report folder, e.g. reports/reach")
    parser.add_argument("--backend", default="local", help="local (processes) or ray")
    parser.add_argument(
        "--workers",
        type=int,
        default=max(1, (os.cpu_count() or 2) // 2),
        help="parallel jobs (default: half the CPUs)",
    )
    parser.add_argument(
        "--address", help="Ray cluster address (backend ray), e.g. ray://host:10001"
    )
    parser.add_argument("--eval-episodes", type=int, default=100, help="held-out episodes per run")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="[ALGO:]KEY=VALUE",
        help="preset override for one algorithm (ppo:n_steps=128) or all (KEY=VALUE)",
    )
    parser.add_argument(
        "--preset",
        action="append",
        default=[],
        metavar="ALGO:NAME",
        help="train ALGO from preset NAME instead of its own (ppo:ppo_kuka_fast_asym)",
    )
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _steps_done(run_dir: Path) -> tuple[int, bool]:
    """(env steps logged, finished) of one run, from the files its trainer writes."""
    finished = False
    with contextlib.suppress(OSError, ValueError):
        finished = bool(json.loads((run_dir / "status.json").read_text()).get("finished"))
    steps = 0
    with contextlib.suppress(OSError, ValueError), open(run_dir / "metrics.jsonl", "rb") as fh:
        fh.seek(max(0, fh.seek(0, os.SEEK_END) - 8192))
        lines = fh.read().splitlines()
        if lines:
            steps = int(json.loads(lines[-1]).get("timesteps", 0))
    return steps, finished


@contextlib.contextmanager
def watch_runs(runs: Path, names: list[str], steps: int, enabled: bool) -> Iterator[None]:
    """A bar over every run's env steps, read from the run dirs the workers write (so it works
    for process and Ray workers alike, with no channel back from them)."""
    from sim2real.progress import progress_bar, progress_enabled

    if not progress_enabled(enabled):
        yield
        return
    bar = progress_bar(len(names) * steps, "compare", "step", enabled)
    stop = threading.Event()

    def refresh() -> None:
        done = [_steps_done(runs / n) for n in names]
        total = sum(steps if fin else min(s, steps) for s, fin in done)
        bar.update(total - bar.n)
        bar.set_postfix_str(f"runs done {sum(fin for _, fin in done)}/{len(names)}")

    def poll() -> None:
        while not stop.wait(1.0):
            refresh()

    thread = threading.Thread(target=poll, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
        refresh()  # the final state, however short the run was
        bar.close()


def run(args: argparse.Namespace) -> int:
    from sim2real.compare.runner import CompareConfig, parse_overrides, parse_presets, run_compare
    from sim2real.errors import ConfigError

    if not args.out:
        raise ConfigError("compare needs --out REPORT_DIR, e.g. --out reports/reach")
    algos = tuple(a.strip().lower() for a in args.algos.split(",") if a.strip())
    cfg = CompareConfig(
        env=args.env,
        algos=algos,
        seeds=args.seeds,
        steps=args.steps,
        out=args.out,
        dr=args.dr,
        backend=args.backend,
        workers=args.workers,
        address=args.address,
        eval_episodes=args.eval_episodes,
        overrides=parse_overrides(args.set, algos),
        presets=parse_presets(args.preset),
    )
    names = [f"{a}-s{seed}" for a in algos for seed in range(args.seeds)]
    progress = not (args.json or args.no_progress)
    with watch_runs(Path(args.out) / "runs", names, args.steps, progress):
        files = run_compare(cfg)
    summary = json.loads(files["results"].read_text())["summary"]
    if args.json:
        print(json.dumps({"files": {k: str(v) for k, v in files.items()}, "summary": summary}))
        return 0
    print(f"report: {files['report']}")
    for algo, s in summary.items():
        lo, hi = s["success_rate_pooled_wilson95"]
        print(
            f"  {algo:5s} success {s['success_rate_pooled']:.1%} [{lo:.1%}, {hi:.1%}]  "
            f"wall {s['wall_s_mean']:.0f} s  {s['steps_per_s_mean']:.0f} steps/s"
        )
    return 0
