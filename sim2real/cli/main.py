"""Entry point of the ``sim2real`` command.

Subcommands live in a registry and are imported only when chosen, so ``sim2real arm ping`` on a
Raspberry Pi never imports torch or MuJoCo. Each subcommand module provides
``add_arguments(parser)`` and ``run(args) -> int``. Long commands treat SIGTERM as Ctrl-C
(``sim2real.cli.signals``) and exit with 130 (SIGINT) or 143 (SIGTERM). A command whose
install extra is missing says, in one line, which extra to install (``EXTRA_OF_MODULE``).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import signal
import sys
from collections.abc import Sequence
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass

from sim2real.cli.examples import describe
from sim2real.cli.signals import SIGNALS, Received, exit_code_for, interrupts_as_keyboard

# Which install extra (pyproject.toml) provides a third-party module a command may import.
EXTRA_OF_MODULE: dict[str, str] = {
    **dict.fromkeys(("cv2", "filterpy", "onnxruntime", "imageio", "threadpoolctl"), "deploy"),
    **dict.fromkeys(("mujoco", "gymnasium", "scipy", "numba", "imageio_ffmpeg", "tqdm"), "sim"),
    **dict.fromkeys(
        ("torch", "stable_baselines3", "onnx", "tensorboard", "matplotlib", "rich", "pyarrow"),
        "train",
    ),
    "robosuite": "robosuite",
    "ray": "ray",
    "rerun": "view",
}


@dataclass(frozen=True)
class Command:
    name: str
    module: str
    help: str
    long: bool = False  # runs for minutes to hours: SIGTERM is handled as Ctrl-C


def missing_extra(exc: ModuleNotFoundError) -> str | None:
    """The extra that would provide the module ``exc`` names; None if no extra does (a bug)."""
    return EXTRA_OF_MODULE.get((exc.name or "").split(".")[0])


COMMANDS: tuple[Command, ...] = (
    Command("envs", "sim2real.cli.envs", "list the registered environments"),
    Command(
        "demo", "sim2real.cli.demo", "run the main job end to end on embedded defaults", long=True
    ),
    Command(
        "train",
        "sim2real.cli.train",
        "train a policy into a run directory (or resume one)",
        long=True,
    ),
    Command("evaluate", "sim2real.cli.evaluate", "held-out success, video, transfer-gap sweep"),
    Command(
        "compare",
        "sim2real.cli.compare",
        "compare algorithms over seeds: report + plots",
        long=True,
    ),
    Command("export", "sim2real.cli.export", "export a policy to ONNX or numpy (no torch)"),
    Command(
        "calibrate", "sim2real.cli.calibrate", "calibrate cameras, check them, register to the arm"
    ),
    Command("arm", "sim2real.cli.arm", "servo arm: emulate, ping, home, jog, calibrate"),
    Command(
        "deploy",
        "sim2real.cli.deploy",
        "run a policy on a simulated, emulated or real arm",
        long=True,
    ),
    Command("sysid", "sim2real.cli.sysid", "fit the servo model to logs; write spec + DR centre"),
    Command(
        "adapt",
        "sim2real.cli.adapt",
        "adapt a policy to the arm it meets: record, fit, fine-tune in sim, evaluate",
        long=True,
    ),
    Command("finetune", "sim2real.cli.finetune", "learn on the mock or real arm", long=True),
    Command("replay", "sim2real.cli.replay", "read a recorded LeRobot dataset back"),
    Command("policies", "sim2real.cli.policies", "list the shipped, measured policies"),
    Command("view", "sim2real.cli.view", "see a run in Rerun: arm, cameras, timing, safety"),
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
        describe(p, cmd.name, cmd.help)  # its examples (and its subcommands', once added)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args_list = list(sys.argv[1:] if argv is None else argv)
    try:
        return _main(args_list)
    except ModuleNotFoundError as exc:
        extra = missing_extra(exc)
        if extra is None:
            raise
        chosen = next((a for a in args_list if not a.startswith("-")), "")
        print(
            f"sim2real {chosen}: needs the '{extra}' extra ({exc.name} is not installed): "
            f"pip install 'sim2real[{extra}]'",
            file=sys.stderr,
        )
        return 2


def _main(args_list: list[str]) -> int:
    parser = build_parser(args_list)
    args = parser.parse_args(args_list)
    known = _known_errors()
    long = next(c.long for c in COMMANDS if c.name == args.command)
    signals: AbstractContextManager[Received] = (
        interrupts_as_keyboard() if long else nullcontext(Received())
    )
    try:
        with signals as received:
            code = int(args._run(args) or 0)
    except KeyboardInterrupt as exc:
        code = exit_code_for(exc)
        print(f"sim2real {args.command}: interrupted ({_signal_name(code)})", file=sys.stderr)
        return code
    except known as exc:
        print(f"sim2real {args.command}: error: {exc}", file=sys.stderr)
        return 2
    if received.exit_code is not None:  # the command stopped cleanly on the signal (deploy)
        print(
            f"sim2real {args.command}: interrupted ({_signal_name(received.exit_code)})",
            file=sys.stderr,
        )
        return received.exit_code
    return code


def console() -> None:
    """The process entry (the ``sim2real`` console script, ``python -m sim2real``): ``main``,
    then exit with its code. A command a signal stopped has stopped cleanly by the time ``main``
    returns 130 or 143 (the arm parked, every file written whole, the message printed); it then
    leaves without the interpreter's teardown, whose native finalizers (EGL, LLVM, torch's
    threads) run over state the KeyboardInterrupt cut through: ``adapt`` interrupted in its
    sysid stage, after rendering in its record stage, once died there by SIGSEGV (exit -11
    after its clean stop was printed), which a caller cannot tell from a crash."""
    code = main()
    if code in {128 + int(s) for s in SIGNALS}:
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    raise SystemExit(code)


def _signal_name(exit_code: int) -> str:
    return "Ctrl-C" if exit_code == 130 else signal.Signals(exit_code - 128).name


if __name__ == "__main__":  # pragma: no cover
    console()
