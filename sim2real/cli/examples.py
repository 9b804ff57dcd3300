"""One worked example per command, shown under its ``--help`` (argparse ``epilog``).

Kept apart from the commands' own modules so a new command shows up in one place;
``tests/sim2real/cli/test_help.py`` parses every example with the real parser, so an example
whose options drift from the command fails the tests, and a command without one does too.
"""

from __future__ import annotations

import argparse

# "command" or "command subcommand" -> example command lines (each parses with the real parser)
EXAMPLES: dict[str, tuple[str, ...]] = {
    "envs": ("sim2real envs", "sim2real envs reach --steps 200"),
    "demo": ("sim2real demo", "sim2real demo --json"),
    "train": (
        "sim2real train --env reach --algo ppo --dr default --seed 0 --run-dir runs/reach-ppo",
        "sim2real train --resume --run-dir runs/reach-ppo",
    ),
    "evaluate": (
        "sim2real evaluate runs/reach-ppo --episodes 200 --dr shifted --json",
        "sim2real evaluate reach-ppo --video reach.mp4",
    ),
    "compare": (
        "sim2real compare --env reach --algos a2c,dqn,ppo --seeds 3 --steps 50000"
        " --out reports/reach",
    ),
    "export": ("sim2real export runs/reach-ppo --format onnx --out reach.onnx",),
    "calibrate": (
        "sim2real calibrate stereo --left tests/data/stereo_chessboard_9x6"
        " --right tests/data/stereo_chessboard_9x6 --board chessboard:9x6:1 --out calib/stereo",
    ),
    "calibrate intrinsics": (
        "sim2real calibrate intrinsics --images 'tests/data/stereo_chessboard_9x6/left*.jpg'"
        " --board chessboard:9x6:1 --name left --out calib/left",
    ),
    "calibrate stereo": (
        "sim2real calibrate stereo --left tests/data/stereo_chessboard_9x6"
        " --right tests/data/stereo_chessboard_9x6 --board chessboard:9x6:1 --out calib/stereo",
        "sim2real calibrate stereo --live --cameras 0,1"
        " --board charuco:7x5:0.04:0.03:DICT_4X4_50 --out calib/stereo",
    ),
    "calibrate check": (
        "sim2real calibrate check --calib calib/stereo/stereo.yaml"
        " --left tests/data/stereo_chessboard_9x6 --right tests/data/stereo_chessboard_9x6"
        " --board chessboard:9x6:1",
    ),
    "calibrate register": ("sim2real calibrate register --points points.csv --out calib/reg",),
    "calibrate cube-sheet": ("sim2real calibrate cube-sheet --out cube.pdf",),
    "arm": ("sim2real arm emulate --protocol s2r --link /tmp/arm3",),
    "arm emulate": (
        "sim2real arm emulate --protocol s2r --link /tmp/arm3",
        "sim2real arm emulate --plant hard --link /tmp/arm3",
    ),
    "arm ping": ("sim2real arm ping --port /tmp/arm3 --protocol s2r",),
    "arm home": ("sim2real arm home --port /tmp/arm3 --protocol s2r",),
    "arm jog": ("sim2real arm jog --port /tmp/arm3 --protocol s2r",),
    "arm calibrate": ("sim2real arm calibrate --port /dev/ttyUSB0 --protocol s2r --arm-id lab1",),
    "arm find-port": ("sim2real arm find-port --unplug",),
    "arm gen-limits": ("sim2real arm gen-limits --out limits.h",),
    "deploy": (
        "sim2real deploy reach-ppo --backend mock --episodes 10 --json",
        "sim2real deploy reach-ppo --backend serial --port /dev/ttyUSB0 --protocol s2r"
        " --perception fk --dry-run",
    ),
    "sysid": (
        "sim2real sysid --record logs/excite.npz --backend mock --protocol feetech",
        "sim2real sysid logs/excite.npz --out my_arm.fitted.yaml --droop --json",
    ),
    "adapt": (
        "sim2real adapt reach-ppo --backend mock --plant moderate --minutes 10 --episodes 20",
    ),
    "finetune": (
        "sim2real finetune reach-ddpg --backend mock --plant hard --minutes 15 --out runs/ft-reach",
    ),
    "replay": ("sim2real replay datasets/pick", "sim2real replay datasets/pick --episode 3 --step"),
    "policies": ("sim2real policies", "sim2real policies reach-ppo"),
    "view": (
        "sim2real view logs/mock.npz --frames datasets/mock --save mock.rrd",
        "sim2real view logs/sim.npz logs/mock.npz --labels sim,mock",
    ),
}


def describe(parser: argparse.ArgumentParser, path: str, help_text: str | None) -> None:
    """Give ``parser`` (the command at ``path``) a one-line description and its examples, then
    do the same for the subcommands it has."""
    if not parser.description and help_text:
        parser.description = help_text
    examples = EXAMPLES.get(path)
    if examples and not parser.epilog:
        parser.epilog = "example:\n" + "\n".join(f"  {line}" for line in examples)
        if parser.formatter_class is argparse.HelpFormatter:  # keep the example's lines
            parser.formatter_class = argparse.RawDescriptionHelpFormatter
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            for name, sub in action.choices.items():
                describe(sub, f"{path} {name}", helps.get(name))
