"""``sim2real train``: train one (env, algo, DR, seed) into a run directory, or resume one."""

from __future__ import annotations

import argparse
import json
from typing import Any

from sim2real.errors import ConfigError

# Flags that define a run; on --resume they must be absent or equal to what the run recorded.
_RUN_FLAGS: dict[str, str] = {
    "env": "env_id",
    "algo": "algo",
    "dr": "dr",
    "seed": "seed",
    "n_envs": "n_envs",
    "vec_env": "vec_env",
    "spec": "spec_path",
    "preset": "preset",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--env", help="env id or short name, e.g. Sim2Real/Arm3Reach-v0 or reach")
    parser.add_argument("--algo", help="ddpg, ppo, td3, sac, a2c, dqn or distill")
    parser.add_argument("--dr", help="DR preset name or YAML path (default: default)")
    parser.add_argument("--steps", type=int, help="total env steps (default: the preset's)")
    parser.add_argument("--seed", type=int, help="training seed (default 0)")
    parser.add_argument("--run-dir", help="output folder (default runs/<env>-<algo>-s<seed>)")
    parser.add_argument("--her", action="store_true", help="hindsight replay (goal envs)")
    parser.add_argument("--n-envs", type=int, help="parallel envs (default: the preset's)")
    parser.add_argument("--vec-env", help="dummy (in-process) or subproc (worker processes)")
    parser.add_argument("--preset", help="hyperparameter preset name or YAML path")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override any preset field, e.g. --set learning_rate=3e-4 --set n_envs=4",
    )
    parser.add_argument("--spec", help="ArmSpec YAML (default: the shipped arm)")
    parser.add_argument(
        "--max-minutes", type=float, help="stop after this much wall time (the model is saved)"
    )
    parser.add_argument(
        "--resume", action="store_true", help="continue RUN_DIR from its checkpoint"
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def _check_resume_flags(args: argparse.Namespace, train_cfg: dict[str, Any]) -> None:
    import sim2real.envs as envs

    for flag, key in _RUN_FLAGS.items():
        given = getattr(args, flag)
        if given is None:
            continue
        if flag == "env":
            given = envs.resolve_env_id(given)
        if flag == "algo":
            given = given.lower()
        recorded = train_cfg.get(key)
        if given != recorded:
            raise ConfigError(
                f"conflicting flags: --{flag.replace('_', '-')} {given} but the run was "
                f"trained with {recorded}; omit it to resume"
            )
    if args.her and not train_cfg.get("her"):
        raise ConfigError("conflicting flags: --her but the run was trained without HER")
    if args.set:
        raise ConfigError("conflicting flags: --set cannot change a run being resumed")


def run(args: argparse.Namespace) -> int:
    import torch

    from sim2real.train import resolve_config, resume, train
    from sim2real.train.rundir import RunDir

    torch.set_num_threads(1)
    progress = not args.no_progress
    if args.resume:
        if not args.run_dir:
            raise ConfigError("--resume needs --run-dir RUN_DIR")
        meta = RunDir(args.run_dir).read_meta()
        _check_resume_flags(args, dict(meta.train))
        result = resume(
            args.run_dir,
            steps=args.steps,
            progress=progress,
            max_wall_s=None if args.max_minutes is None else 60.0 * args.max_minutes,
        )
    else:
        if not args.env or not args.algo:
            raise ConfigError("train needs --env and --algo (or --resume --run-dir RUN_DIR)")
        import sim2real.envs as envs

        seed = 0 if args.seed is None else args.seed
        env_id = envs.resolve_env_id(args.env)
        short = env_id.split("/")[-1].removesuffix("-v0").lower()
        run_dir = args.run_dir or f"runs/{short}-{args.algo.lower()}-s{seed}"
        cfg = resolve_config(
            args.env,
            args.algo,
            run_dir,
            dr=args.dr or "default",
            seed=seed,
            steps=args.steps,
            n_envs=args.n_envs,
            vec_env=args.vec_env,
            her=args.her,
            preset=args.preset,
            overrides=args.set,
            spec_path=args.spec,
            progress=progress,
            max_wall_s=None if args.max_minutes is None else 60.0 * args.max_minutes,
        )
        result = train(cfg)
    summary = {
        "run_dir": str(result.run_dir),
        "steps": result.steps_done,
        "wall_s": round(result.wall_s, 1),
        "steps_per_s": round(result.steps_per_s, 1),
        "train_success_rate": result.train_success_rate,
        "stopped_by_wall_limit": result.stopped_by_wall_limit,
    }
    if args.json:
        print(json.dumps(summary))
    else:
        for k, v in summary.items():
            print(f"{k:20s} {v}")
    return 0
