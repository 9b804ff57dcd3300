"""The README and the docs say what is true of the code: the README stays short, its links
resolve, and every ``sim2real`` command shown in a shell block parses with the real parser."""

import re
import shlex
from pathlib import Path

import pytest

from sim2real.cli.main import build_parser

ROOT = Path(__file__).resolve().parents[1]
# Pages a user copies commands from (the studies keep commands as they were run, some since
# renamed, and the generated benchmark pages quote the records).
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"\]\(([^)#\s]+)(#[^)]*)?\)")


def test_readme_is_short() -> None:
    assert (ROOT / "README.md").stat().st_size <= 15_000


@pytest.mark.parametrize("name", ["README.md", "CHANGELOG.md", "BENCHMARKS.md"])
def test_links_from_the_repository_root_resolve(name: str) -> None:
    text = (ROOT / name).read_text()
    for target, _ in LINK.findall(text):
        if "://" in target or target.startswith("mailto:"):
            continue
        assert (ROOT / target).exists(), f"{name}: dead link {target}"


def _commands(text: str) -> list[str]:
    """``sim2real ...`` lines of the shell blocks, continuation lines joined, comments cut."""
    out = []
    for block in re.findall(r"```(?:bash|sh|console)?\n(.*?)```", text, re.S):
        joined = re.sub(r"\\\n\s*", " ", block)
        for line in joined.splitlines():
            line = line.strip().removeprefix("$ ")
            if not line.startswith("sim2real "):
                continue
            words = shlex.split(line, comments=True)
            if len(words) < 2 or words[1].endswith(":"):  # an error message, not a command
                continue
            out.append(" ".join(shlex.quote(w) for w in words))
    return out


COMMANDS = sorted({(p.name, c) for p in PAGES for c in _commands(p.read_text())})


@pytest.mark.parametrize("page,command", COMMANDS, ids=[f"{p}:{c[:60]}" for p, c in COMMANDS])
def test_shown_commands_parse(page: str, command: str) -> None:
    argv = shlex.split(command)[1:]
    argv = [a for a in argv if a not in ("&", "...")]  # a background job; "and so on"
    try:
        build_parser(argv).parse_args(argv)
    except SystemExit as exc:
        pytest.fail(f"{page}: `{command}` does not parse ({exc.code})")
