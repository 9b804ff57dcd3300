"""``sim2real deploy``: run a trained policy of any task on a simulated, emulated or real arm."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from sim2real.cli.verbosity import add_verbose, configure_logging
from sim2real.deploy.connection import add_arm_options, arm_connection
from sim2real.deploy.replayed import PLACEMENT_SOURCES
from sim2real.errors import ConfigError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "policy", help="a run directory, an exported .onnx / .npz policy, or a shipped policy name"
    )
    add_arm_options(parser, extras=("perception", "markers", "firmware", "camera_fps", "dry_run"))
    parser.add_argument("--spec", default=None, help="ArmSpec YAML (default: the shipped arm)")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument(
        "--steps", type=int, default=None, help="control periods per episode (default: training's)"
    )
    parser.add_argument("--rate", type=float, default=20.0, help="control rate in Hz")
    parser.add_argument("--seed", type=int, default=1_000_000, help="placement seed (held out)")
    parser.add_argument(
        "--placements", default="loop", choices=tuple(PLACEMENT_SOURCES),
        help="sim/mock: where the objects go: the loop's own draws (--seed), or the policy's "
        "held-out evaluation episodes (evaluate --dr none places the same objects)",
    )  # fmt: skip
    parser.add_argument(
        "--start-timeout", type=float, default=10.0,
        help="seconds an episode waits for its objects to be seen and still",
    )  # fmt: skip
    parser.add_argument("--log", type=Path, default=None, help="trajectory log (.npz)")
    parser.add_argument("--video", type=Path, default=None, help="mp4 of the left camera")
    parser.add_argument(
        "--record-dataset", type=Path, default=None, metavar="DIR",
        help="write the episodes as a LeRobot dataset (v3.0; both cameras as videos)",
    )  # fmt: skip
    parser.add_argument(
        "--view",
        metavar="spawn|connect[:ADDR]|save:FILE.rrd",
        default=None,
        help="stream every period to Rerun while the arm runs (the view extra): spawn a viewer, "
        "connect to a running one, or save a recording",
    )
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_verbose(parser)


def _live_view(where: str | None, policy: str, spec: Any, rate_hz: float) -> Any:
    """``--view``: the live viewer's child process, started (a missing extra is named in one
    line; a target it cannot open fails here, before the arm moves)."""
    if where is None:
        return None
    from sim2real.deploy.policy_io import policy_io
    from sim2real.export.policy import load_policy
    from sim2real.policies import resolve_policy
    from sim2real.view.live import LiveJob, LiveProcess

    target, _, address = where.partition(":")
    meta = load_policy(resolve_policy(policy)).meta
    objects = policy_io(spec, meta).contract.objects
    job = LiveJob(spec, objects, target=target, where=address or None, rate_hz=rate_hz)
    return LiveProcess(job).start()


def run(args: argparse.Namespace) -> int:
    from hardware.spec import load_spec
    from sim2real.deploy.loop import LoopConfig
    from sim2real.deploy.replayed import check_source, placements
    from sim2real.deploy.runner import deploy

    configure_logging(args)
    opts = arm_connection(args)
    spec = load_spec(args.spec)
    check_source(args.placements, opts.backend)
    config = LoopConfig(
        placements=placements(args.placements, args.policy, args.episodes),
        rate_hz=args.rate,
        episodes=args.episodes,
        episode_steps=args.steps,
        seed=args.seed,
        dry_run=opts.dry_run,
        start_timeout_s=args.start_timeout,
    )
    if args.record_dataset is not None and args.record_dataset.exists():
        raise ConfigError(f"--record-dataset {str(args.record_dataset)!r} exists; choose a new one")
    live = _live_view(args.view, args.policy, spec, args.rate)
    try:
        result = deploy(
            args.policy, spec, opts, config, log_path=args.log, video_path=args.video,
            dataset_path=args.record_dataset, live=live,
        )  # fmt: skip
    finally:
        if live is not None:
            live.close()  # the child draws what it was sent, flushes its sink and goes
    summary = {"backend": opts.backend, **result.summary().to_json()}
    if live is not None:  # what the viewer skipped to keep up (a drop never slows the arm)
        summary["live_view"] = {"drawn": live.drawn, "dropped": live.dropped,
                                "failed": live.failed}  # fmt: skip
    if args.json:
        print(json.dumps(summary))
    else:
        for key, value in summary.items():
            print(f"{key:22s} {value}")
    return 0 if result.stopped_early is None else 1
