"""``sim2real adapt POLICY``: record on the arm, fit, fine-tune in sim, export, evaluate on the arm.

Stages and files: ``sim2real.adapt.pipeline``. Ctrl-C / SIGTERM stop it cleanly (the arm parked,
finished stages kept); running it again with the same ``--out`` (or ``--resume``) continues.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
from pathlib import Path

from sim2real.cli.verbosity import add_verbose, configure_logging
from sim2real.deploy.connection import add_arm_options, arm_connection
from sim2real.deploy.replayed import PLACEMENT_SOURCES
from sim2real.errors import ConfigError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from sim2real.adapt.pipeline import RUNS_ON

    parser.add_argument("policy", help="a run directory or a shipped policy name (with checkpoint)")
    add_arm_options(parser, RUNS_ON)
    parser.add_argument(
        "--out", type=Path, default=None, help="output folder (default runs/adapt-<policy>-<utc>)"
    )
    parser.add_argument(
        "--resume", action="store_true", help="continue --out (it must exist; same options)"
    )
    parser.add_argument(
        "--minutes", type=float, default=10.0, help="fine-tune wall-clock budget (default 10)"
    )
    parser.add_argument(
        "--finetune-steps", type=int, default=None, help="cap on fine-tune env steps"
    )
    parser.add_argument(
        "--episodes", type=int, default=20, help="deploy episodes before and after (default 20)"
    )
    parser.add_argument(
        "--logs", nargs="+", type=Path, default=(), metavar="LOG",
        help="take these logs instead of recording: servo excitation logs (sysid --record) and "
        "logs with wrist-marker observations (deploy --log)",
    )  # fmt: skip
    parser.add_argument(
        "--kinematic-s", type=float, default=60.0, help="kinematic excitation length in s"
    )
    parser.add_argument("--servo-rate", type=float, default=100.0, help="servo excitation Hz")
    parser.add_argument("--spec", default=None, help="ArmSpec YAML (default: the shipped arm)")
    parser.add_argument(
        "--start-timeout", type=float, default=10.0, help="seconds an episode waits for its objects"
    )
    parser.add_argument("--seed", type=int, default=1_000_000, help="deploy placement seed")
    parser.add_argument(
        "--placements", default="loop", choices=tuple(PLACEMENT_SOURCES),
        help="mock: the deploys' objects from the loop's draws (--seed) or the policy's held-out "
        "evaluation episodes (the same as evaluate --dr none places)",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="one JSON line per stage")
    add_verbose(parser)


def _default_out(policy: str) -> Path:
    stem = Path(policy).name or "policy"
    utc = dt.datetime.now(dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    return Path("runs") / f"adapt-{stem}-{utc}"


def run(args: argparse.Namespace) -> int:
    from sim2real.adapt.figures import StageResult
    from sim2real.adapt.pipeline import Adapter, AdaptOptions, DeployInterruptedError, summary_table

    if args.resume and args.out is None:
        raise ConfigError("--resume needs --out: the folder of the adaptation to continue")
    if args.resume and not (args.out / "status.json").is_file():
        raise ConfigError(f"--resume: {str(args.out)!r} holds no adaptation (no status.json)")
    opts = AdaptOptions(
        policy=args.policy,
        out=args.out or _default_out(args.policy),
        arm=arm_connection(args),
        spec=args.spec,
        minutes=args.minutes,
        finetune_steps=args.finetune_steps,
        episodes=args.episodes,
        logs=tuple(args.logs),
        servo_rate_hz=args.servo_rate,
        kinematic_s=args.kinematic_s,
        start_timeout_s=args.start_timeout,
        seed=args.seed,
        placements=args.placements,
    )

    def report(result: StageResult) -> None:
        stage, figures = result.stage, result.to_json()  # JSON only here, at the edge
        if args.json:
            print(json.dumps({"stage": stage, **figures}), flush=True)
        else:
            print(f"[{stage}] " + ", ".join(f"{k}={v}" for k, v in figures.items()), flush=True)

    def on_start(stage: str) -> None:
        print(f"sim2real adapt: stage {stage} started", file=sys.stderr, flush=True)

    configure_logging(args)
    adapter = Adapter(opts, report, on_start)
    print(f"sim2real adapt: {opts.out}", file=sys.stderr, flush=True)
    try:
        results = adapter.run()
    except (
        DeployInterruptedError
    ) as exc:  # the deploy loop stopped cleanly; main reports the signal
        print(f"sim2real adapt: {exc}", file=sys.stderr)
        return 1
    table = summary_table(results)
    print(table, file=sys.stderr if args.json else sys.stdout, flush=True)
    return 0
