"""Entry point of the ``sim2real`` command.

Subcommands live in a registry and are imported only when chosen, so ``sim2real arm ping`` on a
Raspberry Pi never imports torch or MuJoCo. Each subcommand module provides
``add_arguments(parser)`` and ``run(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class Command:
    name: str
    module: str
    help: str


COMMANDS: tuple[Command, ...] = (
    Command("envs", "sim2real.cli.envs", "list the registered environments"),
    Command("demo", "sim2real.cli.demo", "run the main job end to end on embedded defaults"),
    Command("train", "sim2real.cli.train", "train a policy into a run directory (or resume one)"),
    Command("evaluate", "sim2real.cli.evaluate", "held-out success, video, transfer-gap sweep"),
    Command("compare", "sim2real.cli.compare", "compare algorithms over seeds: report + plots"),
    Command("export", "sim2real.cli.export", "export a policy to ONNX or numpy (no torch)"),
    Command(
        "calibrate", "sim2real.cli.calibrate", "calibrate cameras, check them, register to the arm"
    ),
    Command("arm", "sim2real.cli.arm", "servo arm: emulate, ping, home, jog, calibrate"),
    Command("deploy", "sim2real.cli.deploy", "run a policy on a simulated, emulated or real arm"),
    Command("sysid", "sim2real.cli.sysid", "fit the servo model to logs; write spec + DR centre"),
    Command("replay", "sim2real.cli.replay", "read a recorded LeRobot dataset back"),
)


def _known_errors() -> tuple[type[BaseException], ...]:
    """Errors that are the user's input, not a bug: printed as one line, exit code 2."""
    from hardware.errors import HardwareError
    from sim2real.errors import Sim2RealError

    errors: list[type[BaseException]] = [Sim2RealError, HardwareError]
    try:
        from calibration.errors import CalibrationError

        errors.append(CalibrationError)
    except ImportError:  # pragma: no cover - calibration is part of the distribution
        pass
    return tuple(errors)


def build_parser(argv: Sequence[str]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sim2real",
        description="Train in domain-randomised simulation; run the same policy on a servo arm.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    chosen = next((a for a in argv if not a.startswith("-")), None)
    for cmd in COMMANDS:
        p = sub.add_parser(cmd.name, help=cmd.help, description=cmd.help)
        if cmd.name == chosen:
            module = importlib.import_module(cmd.module)
            module.add_arguments(p)
            p.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args_list = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(args_list)
    args = parser.parse_args(args_list)
    known = _known_errors()
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("sim2real: interrupted", file=sys.stderr)
        return 130
    except known as exc:
        print(f"sim2real {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
