"""``sim2real export RUN --format onnx|numpy --out FILE``: a torch-free policy for the robot."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="run directory, or a shipped policy's name")
    parser.add_argument("--format", default="onnx", help="onnx (onnxruntime) or numpy (.npz)")
    parser.add_argument("--out", help="output file (default RUN/policy.onnx or RUN/policy.npz)")
    parser.add_argument(
        "--check", type=int, default=1000, metavar="N", help="parity check on N observations"
    )
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    import torch

    from sim2real.errors import ConfigError
    from sim2real.evaluate.parity import check_parity
    from sim2real.export.exporter import export_policy
    from sim2real.export.formats import get_format

    torch.set_num_threads(1)
    suffix = get_format(args.format).suffix
    if not Path(args.run).exists():  # a shipped policy is exported already: copy it out
        return _export_shipped(args, suffix)
    if args.check < 0:
        raise ConfigError(f"--check {args.check} must be >= 0")
    out = args.out or f"{args.run.rstrip('/')}/policy{suffix}"
    path = export_policy(args.run, args.format, out)
    summary: dict[str, object] = {"out": str(path), "format": args.format}
    if args.check:  # discrete policies add action disagreements and the largest score diff
        summary.update(check_parity(args.run, path, args.check).to_dict())
    if args.json:
        print(json.dumps(summary))
    else:
        for k, v in summary.items():
            print(f"{k:20s} {v}")
    return 0


def _export_shipped(args: argparse.Namespace, suffix: str) -> int:
    """A shipped policy in its own format, written where the user asks (atomically)."""
    from hardware.atomic import atomic_write_bytes
    from sim2real.errors import ConfigError
    from sim2real.policies import resolve_policy

    src = resolve_policy(args.run)
    if src.suffix != suffix:
        raise ConfigError(
            f"shipped policy {args.run!r} is exported as {src.suffix}; {args.format} needs its run "
            f"directory (--format {src.suffix.lstrip('.')} copies it)"
        )
    out = Path(args.out or f"{args.run}{suffix}")
    atomic_write_bytes(out, src.read_bytes())
    summary = {"out": str(out), "format": args.format, "shipped": args.run}
    print(
        json.dumps(summary) if args.json else "\n".join(f"{k:20s} {v}" for k, v in summary.items())
    )
    return 0
