"""The fault table in docs/hardware.md cannot go stale: every row names at least one test, and
every test it names exists as a test function in that file."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "hardware.md"
REQUIRED = ("cut serial link", "brown-out", "jammed joint / stall", "false marker jump",
            "frozen frames", "blind beyond the limit")  # fmt: skip


def _rows() -> list[list[str]]:
    text = PAGE.read_text()
    start = text.index("### Faults injected, and how they end")
    table = [ln for ln in text[start:].splitlines() if ln.startswith("|")]
    header, _, *body = table
    assert [c.strip() for c in header.strip("|").split("|")] == [
        "fault", "where injected", "outcome", "log kept", "proved by",
    ]  # fmt: skip
    return [[c.strip() for c in row.strip("|").split("|")] for row in body]


def _test_functions(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    return {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)
            and n.name.startswith("test_")}  # fmt: skip


def test_every_fault_row_names_tests_that_exist() -> None:
    rows = _rows()
    assert len(rows) >= len(REQUIRED)
    for fault, *_, proved_by in rows:
        named = re.findall(r"`([^`:]+\.py)::(test_\w+)`", proved_by)
        assert named, f"fault {fault!r} names no test"
        for file, func in named:
            path = ROOT / file
            assert path.is_file(), f"fault {fault!r}: no test file {file}"
            assert func in _test_functions(path), f"fault {fault!r}: {file} has no {func}"


def test_the_table_has_the_faults_the_issue_asks_for() -> None:
    faults = [row[0] for row in _rows()]
    for fault in REQUIRED:
        assert any(f.startswith(fault) for f in faults), f"no row for {fault!r}: {faults}"
