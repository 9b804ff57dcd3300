"""The CLI reference page, written from the real argparse parsers at build time.

``mkdocs build`` calls ``on_files`` (this file is a hook in ``mkdocs.yml``), which adds
``cli.md`` to the site: every command of ``sim2real.cli.main`` and every subcommand, with its
description, usage, arguments and examples, as the parser itself states them. Nothing here is
copied help text, so the page cannot drift from the commands. ``python docs/hooks/cli_reference.py``
prints the same Markdown.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]


def _subparsers(parser: argparse.ArgumentParser) -> argparse._SubParsersAction[Any] | None:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action
    return None


def _cell(text: object) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ").strip()


def _argument_rows(parser: argparse.ArgumentParser) -> list[str]:
    rows = []
    for a in parser._actions:
        if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        if a.option_strings:
            name = ", ".join(f"`{s}`" for s in a.option_strings)
            if a.nargs != 0:
                metavar = a.metavar or (
                    "{" + ",".join(map(str, a.choices)) + "}" if a.choices else a.dest.upper()
                )
                name += f" `{metavar if isinstance(metavar, str) else ' '.join(metavar)}`"
        else:
            name = f"`{a.metavar or a.dest}`"
        default = ""
        if a.default not in (None, False, argparse.SUPPRESS) and a.nargs != 0:
            default = f"`{a.default}`"
        text = a.help if a.help and a.help != argparse.SUPPRESS else ""
        if a.required and a.option_strings:
            text = f"(required) {text}"
        rows.append(f"| {_cell(name)} | {_cell(default)} | {_cell(text)} |")
    return rows


def _section(parser: argparse.ArgumentParser, path: str, level: int) -> list[str]:
    lines = [f"{'#' * level} `sim2real {path}`", ""]
    if parser.description:
        lines += [parser.description.strip(), ""]
    usage = parser.format_usage().strip()
    lines += ["```text", usage, "```", ""]
    rows = _argument_rows(parser)
    if rows:
        lines += ["| argument | default | what |", "|---|---|---|", *rows, ""]
    if parser.epilog:
        examples = [ln.strip() for ln in parser.epilog.splitlines()[1:] if ln.strip()]
        lines += ["Example:", "", "```bash", *examples, "```", ""]
    subs = _subparsers(parser)
    if subs is not None:
        for name, sub in subs.choices.items():
            lines += _section(sub, f"{path} {name}", level + 1)
    return lines


def markdown() -> str:
    """The whole reference, one section per command, in the registry's order."""
    if str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))
    from sim2real.cli.main import COMMANDS, build_parser

    lines = [
        "# CLI reference",
        "",
        "<!-- Generated at build time by docs/hooks/cli_reference.py from the argparse parsers. -->",
        "",
        "Every `sim2real` command and subcommand, as its parser states it (`sim2real COMMAND "
        "--help` prints the same). Commands that run for minutes treat SIGTERM as Ctrl-C and "
        "exit 130 or 143; bad input exits 2 with one line naming the problem.",
        "",
        "| command | what |",
        "|---|---|",
        *(f"| [`{c.name}`](#sim2real-{c.name}) | {_cell(c.help)} |" for c in COMMANDS),
        "",
    ]
    for cmd in COMMANDS:
        top = build_parser([cmd.name])
        subs = _subparsers(top)
        assert subs is not None
        lines += _section(subs.choices[cmd.name], cmd.name, 2)
    return "\n".join(lines).rstrip() + "\n"


def on_files(files: Any, config: Any) -> Any:
    """mkdocs hook: add the generated ``cli.md`` to the site's files."""
    from mkdocs.structure.files import File

    files.append(File.generated(config, "cli.md", content=markdown()))
    return files


if __name__ == "__main__":
    print(markdown(), end="")
