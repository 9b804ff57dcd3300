"""``sim2real policies``: the shipped, measured policies, usable by name wherever a run
directory is (``sim2real deploy pick-ppo --backend mock``)."""

from __future__ import annotations

import argparse
import json
import shutil
import textwrap
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sim2real.policies import ShippedPolicy


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
    print(_table(list(ships.values()), shutil.get_terminal_size().columns))
    return 0


def _success(figures: dict[str, object]) -> str:
    """Held-out success on DR default / none, as the card measured it."""
    parts = []
    for key in ("env_success_dr_default", "env_success_dr_none"):
        value = figures.get(key)
        parts.append(f"{100 * value:.1f} %" if isinstance(value, (int, float)) else "-")
    return " / ".join(parts)


def _table(ships: list[ShippedPolicy], width: int) -> str:
    """Columns sized to their longest entry. The summary wraps in its own column where the
    terminal is wide enough, else on indented lines under its row."""
    header = ("name", "task", "algo", "env", "success default / none", "summary")
    rows = [(p.name, p.task, p.algo, p.env_id, _success(p.figures), p.summary) for p in ships]
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header) - 1)]
    indent = sum(widths) + 2 * len(widths)
    beside = width - indent >= 40
    lines = []
    for i, row in enumerate([header, *rows]):
        cells = "  ".join(c.ljust(w) for c, w in zip(row[:-1], widths, strict=True))
        if beside:
            summary = textwrap.wrap(row[-1], width - indent, break_on_hyphens=False) or [""]
            lines.append(f"{cells}  {summary[0]}".rstrip())
            lines.extend(" " * indent + more for more in summary[1:])
        else:
            lines.append(cells.rstrip())
            if i:  # the header's "summary" needs no line of its own
                lines.extend(
                    textwrap.wrap(
                        row[-1],
                        max(width, 40),
                        initial_indent="    ",
                        subsequent_indent="    ",
                        break_on_hyphens=False,
                    )
                )
    return "\n".join(lines)
