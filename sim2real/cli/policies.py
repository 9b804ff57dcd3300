"""``sim2real policies``: the shipped, measured policies, usable by name wherever a run
directory is (``sim2real deploy pick-ppo --backend mock``)."""

from __future__ import annotations

import argparse
import json


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", nargs="?", help="show one policy's card")
    parser.add_argument("--json", action="store_true", help="machine-readable")


def run(args: argparse.Namespace) -> int:
    from sim2real.errors import UnknownNameError
    from sim2real.policies import shipped

    ships = shipped()
    if args.name is not None:
        if args.name not in ships:
            raise UnknownNameError("shipped policy", args.name, ships)
        p = ships[args.name]
        card = {
            "name": p.name,
            "file": str(p.path),
            "task": p.task,
            "env_id": p.env_id,
            "algo": p.algo,
            "summary": p.summary,
            "figures": p.figures,
            "trained": p.trained,
        }
        print(json.dumps(card, indent=None if args.json else 2))
        return 0
    if args.json:
        print(json.dumps({n: {"task": p.task, "algo": p.algo, "figures": p.figures}
                          for n, p in ships.items()}))  # fmt: skip
        return 0
    print(f"{'name':<12} {'task':<6} {'algo':<5} {'env':<26} summary")
    for p in ships.values():
        print(f"{p.name:<12} {p.task:<6} {p.algo:<5} {p.env_id:<26} {p.summary}")
    return 0
