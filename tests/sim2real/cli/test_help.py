"""Every command's ``--help`` has a one-line description and a worked example that parses."""

import argparse
import shlex

import pytest

from sim2real.cli.examples import EXAMPLES
from sim2real.cli.main import COMMANDS, build_parser


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _walk(parser: argparse.ArgumentParser, path: str) -> list[tuple[str, argparse.ArgumentParser]]:
    out = [(path, parser)]
    for name, sub in _subcommands(parser).items():
        out.extend(_walk(sub, f"{path} {name}"))
    return out


def _every_command() -> list[tuple[str, argparse.ArgumentParser]]:
    found = []
    for cmd in COMMANDS:
        top = build_parser([cmd.name])  # builds that command's full argument tree
        found.extend(_walk(_subcommands(top)[cmd.name], cmd.name))
    return found


COMMANDS_FOUND = _every_command()


@pytest.mark.parametrize("path,parser", COMMANDS_FOUND, ids=[p for p, _ in COMMANDS_FOUND])
def test_help_has_description_and_example(path: str, parser: argparse.ArgumentParser) -> None:
    text = parser.format_help()
    assert parser.description, f"sim2real {path}: no description"
    assert "\n" not in parser.description.strip(), f"sim2real {path}: description is not one line"
    assert parser.epilog and parser.epilog.startswith("example:"), f"sim2real {path}: no example"
    assert f"  sim2real {path}" in text, f"sim2real {path}: the example is not of this command"


@pytest.mark.parametrize("path", sorted(EXAMPLES))
def test_examples_parse_with_the_real_parser(path: str) -> None:
    assert path in dict(COMMANDS_FOUND), f"an example for a command that does not exist: {path}"
    for line in EXAMPLES[path]:
        argv = shlex.split(line)[1:]
        try:
            build_parser(argv).parse_args(argv)
        except SystemExit as exc:  # argparse exits 2 on an unknown option or a missing value
            pytest.fail(f"example does not parse ({exc.code}): {line}")
