"""``sim2real envs``: list the registered ids, show an observation layout, or smoke-step one."""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("env", nargs="?", help="an id or short name: show its layout and step it")
    parser.add_argument("--dr", default="default", help="DR preset name or YAML path")
    parser.add_argument("--spec", default=None, help="ArmSpec YAML (default: the shipped arm)")
    parser.add_argument("--steps", type=int, default=100, help="random steps to take with ENV")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="machine-readable output")


def run(args: argparse.Namespace) -> int:
    import sim2real.envs as envs
    from hardware.spec import load_spec

    if args.env is None:
        rows = [{"id": e.id, "short": e.short, "doc": e.doc, **e.kwargs} for e in envs.ENV_TABLE]
        if args.json:
            print(json.dumps(rows))
        else:
            for r in rows:
                print(f"{r['id']:34s} {r['short']:14s} {r['doc']}")
        return 0
    env_id = envs.resolve_env_id(args.env)
    spec = load_spec(args.spec)
    kwargs = {"dr": args.dr}
    if env_id.startswith("Sim2Real/Arm3"):  # the hobby arm's envs take its spec
        kwargs["spec"] = spec
    env = envs.make(env_id, **kwargs)
    try:
        base = env.unwrapped
        env.reset(seed=args.seed)
        env.action_space.seed(args.seed)
        t0 = time.perf_counter()
        successes = 0
        for _ in range(args.steps):
            _, _, term, trunc, info = env.step(env.action_space.sample())
            if term or trunc:
                successes += int(info.get("is_success", False))
                env.reset()
        rate = args.steps / (time.perf_counter() - t0)
        builder = getattr(base, "builder", None)  # pixel-only envs have no vector layout
        layout = [
            {"name": f.name, "slice": [f.start, f.stop], "unit": f.unit, "doc": f.doc}
            for f in (builder.layout() if builder is not None else [])
        ]
        dr_config = getattr(base, "dr_config", None)
        dt = getattr(base, "control_dt_s", None)
        summary = {
            "id": env_id,
            "dr": dr_config.name if dr_config is not None else args.dr,
            "spec": spec.name if "spec" in kwargs else None,
            "observation_space": str(env.observation_space),
            "action_space": str(env.action_space),
            "frame_skip": getattr(base, "frame_skip", None),
            "control_hz": 1.0 / dt if dt else None,
            "layout": layout,
            "steps": args.steps,
            "steps_per_s": round(rate, 1),
            "random_policy_successes": successes,
        }
        if args.json:
            print(json.dumps(summary))
        else:
            for key, value in summary.items():
                if key != "layout":
                    print(f"{key:24s} {value}")
            print("observation layout (obs_mode=state/goal 'observation'):")
            width = max((len(f["name"]) for f in layout), default=0)
            for f in layout:
                lo, hi = f["slice"]
                print(f"  [{lo:2d}:{hi:2d}] {f['name']:{width}s} {f['unit']:4s} {f['doc']}")
        return 0 if np.isfinite(rate) else 1
    finally:
        env.close()
