"""``sim2real demo``: the main job end to end on embedded defaults, as named stages.

train (a short PPO reach run) → evaluate (held-out seeds, training DR and the held-out ``shifted``
preset) → export (ONNX, parity-checked) → deploy (the ONNX policy on the mock arm) → pick (the
shipped pick policy grasping the marker cube on the mock arm). Each stage reads what earlier ones
left in ``DemoContext.results``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sim2real.errors import ConfigError, RunDirError, UnknownNameError

DEMO_ENV = "Sim2Real/Arm3Reach-v0"
DEMO_ALGO = "ppo"
DEMO_STEPS = 120_000  # 76 s of training when the 2-core CPU is shared; 98.5% at 1 cm
DEMO_EPISODES = 200
DEMO_MARKER = "demo.json"  # only a folder holding this marker is replaced by the next demo


@dataclass
class DemoContext:
    out: Path  # the demo folder: marker, run/ and whatever later stages write
    steps: int
    seed: int
    episodes: int
    progress: bool
    results: dict[str, dict[str, Any]] = field(default_factory=dict)

    @property
    def run_dir(self) -> Path:
        return self.out / "run"


@dataclass(frozen=True)
class Stage:
    name: str
    help: str
    run: Callable[[DemoContext], dict[str, Any]]
    # One line for the closing table, from the stage's figures.
    summarize: Callable[[dict[str, Any]], str] = lambda figures: ""


def _train(ctx: DemoContext) -> dict[str, Any]:
    from sim2real.train import resolve_config, train
    from sim2real.train.atomic import atomic_write_json

    if ctx.out.exists() and any(ctx.out.iterdir()):
        if not (ctx.out / DEMO_MARKER).is_file():
            raise RunDirError(
                f"{str(ctx.out)!r} exists and is not a demo folder; pass another --out"
            )
        shutil.rmtree(ctx.out)
    atomic_write_json(ctx.out / DEMO_MARKER, {"demo": True, "stages": [s.name for s in STAGES]})
    from sim2real.train.cache import QUICK_REACH_OVERRIDES

    cfg = resolve_config(
        DEMO_ENV,
        DEMO_ALGO,
        ctx.run_dir,
        dr="default",
        seed=ctx.seed,
        steps=ctx.steps,
        progress=ctx.progress,
        overrides=QUICK_REACH_OVERRIDES,
    )
    result = train(cfg)
    return {
        "run_dir": str(result.run_dir),
        "env": DEMO_ENV,
        "algo": DEMO_ALGO,
        "steps": result.steps_done,
        "wall_s": round(result.wall_s, 1),
        "steps_per_s": round(result.steps_per_s),
    }


def _evaluate(ctx: DemoContext) -> dict[str, Any]:
    from sim2real.evaluate import EvalTarget, evaluate

    target = EvalTarget.load(ctx.run_dir)
    out: dict[str, Any] = {}
    for dr in ("default", "shifted"):
        r = evaluate(target, ctx.episodes, dr, progress=ctx.progress)
        out[dr] = {
            "success_rate": r["success_rate"],
            "wilson95": [round(x, 4) for x in r["success_rate_wilson95"]],
            "median_final_distance_mm": round(1000 * r["median_final_distance_m"], 2),
            "episodes": r["episodes"],
        }
    base = out["default"]["success_rate"]
    out["shifted_over_default"] = out["shifted"]["success_rate"] / base if base else None
    return out


def _export(ctx: DemoContext) -> dict[str, Any]:
    from sim2real.evaluate.parity import parity_check
    from sim2real.export.exporter import export_policy

    path = export_policy(ctx.run_dir, "onnx", ctx.run_dir / "policy.onnx")
    return {"onnx": str(path), "max_abs_action_diff": parity_check(ctx.run_dir, path, 1000)}


DEMO_MOCK_EPISODES = 10


def _deploy_mock(ctx: DemoContext) -> dict[str, Any]:
    """The exported ONNX policy (no torch) on the mock arm: the emulated firmware on a pty and
    two rendered cameras through detection, triangulation and the Kalman filter."""
    from hardware.spec import load_spec
    from sim2real.deploy.loop import LoopConfig
    from sim2real.deploy.runner import DeployOptions, deploy

    policy = ctx.results.get("export", {}).get("onnx") or ctx.run_dir
    result = deploy(
        policy,
        load_spec(),
        DeployOptions(backend="mock"),
        LoopConfig(episodes=DEMO_MOCK_EPISODES),
        log_path=ctx.out / "mock_deploy.npz",
    )
    s = result.summary()
    return {
        "policy": str(policy),
        "episodes": s.episodes,
        "success_rate": s.success_rate,
        "mean_final_distance_mm": round(1000 * s.mean_final_distance_m, 2),
        "loop_hz": round(s.loop_hz, 2),
        "period_jitter_ms": {k: round(v, 2) for k, v in s.period_jitter_ms.to_json().items()},
        "sections_ms_p50": {k: round(v.p50, 2) for k, v in s.sections_ms.items()},
        "log": str(ctx.out / "mock_deploy.npz"),
    }


DEMO_PICK_POLICY = "pick-ppo"
DEMO_PICK_EPISODES = 5


def _pick_mock(ctx: DemoContext) -> dict[str, Any]:
    """The shipped pick policy on the mock arm: serial bytes → firmware model → servo dynamics →
    contact physics → rendered frames → cube tracker → observation → policy."""
    from hardware.spec import load_spec
    from sim2real.deploy.loop import LoopConfig
    from sim2real.deploy.runner import DeployOptions, deploy

    result = deploy(
        DEMO_PICK_POLICY,
        load_spec(),
        DeployOptions(backend="mock"),
        LoopConfig(episodes=DEMO_PICK_EPISODES),
        log_path=ctx.out / "mock_pick.npz",
    )
    s = result.summary()
    figures = s.task_figures
    return {
        "policy": DEMO_PICK_POLICY,
        "episodes": s.episodes,
        "success_rate": s.success_rate,
        "grasped_rate": figures.get("grasped_ever_rate"),
        "mean_max_lift_mm": round(1000 * figures.get("mean_max_lift_m", 0.0), 1),
        "mean_cube_blind_max_s": figures.get("mean_cube_blind_max_s"),
        "loop_hz": round(s.loop_hz, 2),
        "log": str(ctx.out / "mock_pick.npz"),
    }


def _sum_pick(f: dict[str, Any]) -> str:
    return (
        f"mock arm {_pct(f['success_rate'])} of {f['episodes']} picks, grasped "
        f"{_pct(f['grasped_rate'])}, lift {f['mean_max_lift_mm']} mm"
    )


def _pct(rate: float | None) -> str:
    return "n/a" if rate is None else f"{100 * rate:.1f}%"


def _sum_train(f: dict[str, Any]) -> str:
    env = str(f["env"]).split("/")[-1]
    return f"{f['algo'].upper()} {env}, {f['steps']:,} steps, {f['steps_per_s']:,} steps/s"


def _sum_evaluate(f: dict[str, Any]) -> str:
    parts = []
    for dr in ("default", "shifted"):
        lo, hi = f[dr]["wilson95"]
        parts.append(f"{dr} {_pct(f[dr]['success_rate'])} [{100 * lo:.1f}, {100 * hi:.1f}]")
    return f"{', '.join(parts)}; {f['default']['episodes']} held-out eps"


def _sum_export(f: dict[str, Any]) -> str:
    return f"ONNX, max action diff {f['max_abs_action_diff']:.1e} vs torch"


def _sum_deploy(f: dict[str, Any]) -> str:
    return (
        f"mock arm {_pct(f['success_rate'])} of {f['episodes']}, {f['loop_hz']} Hz, "
        f"{f['mean_final_distance_mm']} mm"
    )


STAGES: list[Stage] = [
    Stage("train", "train a PPO reach policy with DR 'default'", _train, _sum_train),
    Stage("evaluate", "held-out episodes under 'default' and 'shifted'", _evaluate, _sum_evaluate),
    Stage("export", "ONNX export with a 1,000-observation parity check", _export, _sum_export),
    Stage(
        "deploy",
        "the ONNX policy on the mock arm: emulator on a pty + rendered cameras",
        _deploy_mock,
        _sum_deploy,
    ),
    Stage(
        "pick",
        "the shipped pick policy on the mock arm: physics, the marker cube, its tracker",
        _pick_mock,
        _sum_pick,
    ),
]
DEMO_RESULTS = "results.json"  # every figure of the last demo, beside its marker


def summary_table(results: dict[str, dict[str, Any]], total_s: float) -> str:
    """The closing table a person reads: one line per stage, its time, the total."""
    by_name = {s.name: s for s in STAGES}
    rows = [
        (name, by_name[name].summarize(figures), f"{figures.get('stage_s', 0.0):.1f} s")
        for name, figures in results.items()
    ]
    rows.append(("total", "", f"{total_s:.1f} s"))
    w0 = max(len(r[0]) for r in rows)
    w1 = max(len(r[1]) for r in rows)
    w2 = max(len(r[2]) for r in rows)
    rule = f"+-{'-' * w0}-+-{'-' * w1}-+-{'-' * w2}-+"
    lines = [rule, f"| {'stage':<{w0}} | {'result':<{w1}} | {'time':>{w2}} |", rule]
    lines += [f"| {a:<{w0}} | {b:<{w1}} | {c:>{w2}} |" for a, b, c in rows[:-1]]
    lines += [rule, f"| {rows[-1][0]:<{w0}} | {'':<{w1}} | {rows[-1][2]:>{w2}} |", rule]
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="runs/demo", help="demo folder, replaced on each run")
    parser.add_argument("--steps", type=int, default=DEMO_STEPS, help="training env steps")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=DEMO_EPISODES, help="held-out episodes")
    parser.add_argument(
        "--stages",
        default=",".join(s.name for s in STAGES),
        help="comma-separated stages to run, in order",
    )
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument("--json", action="store_true", help="print all figures as one JSON object")


def run(args: argparse.Namespace) -> int:
    import torch

    torch.set_num_threads(1)
    by_name = {s.name: s for s in STAGES}
    chosen = [n.strip() for n in args.stages.split(",") if n.strip()]
    for name in chosen:
        if name not in by_name:
            raise UnknownNameError("demo stage", name, by_name)
    if args.steps < 1 or args.episodes < 1:
        raise ConfigError(f"--steps {args.steps} and --episodes {args.episodes} must be >= 1")
    ctx = DemoContext(Path(args.out), args.steps, args.seed, args.episodes, not args.no_progress)
    t_start = time.perf_counter()
    for name in chosen:
        stage = by_name[name]
        if not args.json:
            print(f"== {stage.name}: {stage.help}", flush=True)
        t0 = time.perf_counter()
        figures = stage.run(ctx)
        figures["stage_s"] = round(time.perf_counter() - t0, 1)
        ctx.results[name] = figures
        if not args.json:
            print(f"   {stage.summarize(figures)} ({figures['stage_s']} s)", flush=True)
    total = round(time.perf_counter() - t_start, 1)
    everything = {"stages": ctx.results, "total_s": total}
    if ctx.out.is_dir():
        from sim2real.train.atomic import atomic_write_json

        atomic_write_json(ctx.out / DEMO_RESULTS, everything)
    if args.json:
        print(json.dumps(everything))
    else:
        print(summary_table(ctx.results, total))
        print(f"outputs in {ctx.out}; every figure in {ctx.out / DEMO_RESULTS} (or use --json)")
    return 0
