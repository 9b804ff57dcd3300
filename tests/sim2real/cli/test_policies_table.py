"""``sim2real policies``: the columns line up whatever the longest name, at any terminal width."""

import pytest

from sim2real.cli.policies import _table
from sim2real.policies import shipped


@pytest.mark.parametrize("width", [80, 120, 200])
def test_columns_line_up(width: int) -> None:
    ships = list(shipped().values())
    lines = _table(ships, width).splitlines()
    header = lines[0]
    rows = [ln for ln in lines[1:] if not ln.startswith(" ")]
    assert len(rows) == len(ships)
    for column in ("task", "algo", "env", "success"):
        start = header.index(column)
        for row in rows:  # every cell starts where its header does, after a gap
            assert row[start - 2 : start] == "  " and row[start] != " ", (column, row)
    assert {row.split()[0] for row in rows} == {p.name for p in ships}


def test_a_long_name_widens_its_column() -> None:
    ships = list(shipped().values())
    longest = max(len(p.name) for p in ships)
    assert _table(ships, 200).splitlines()[0].index("task") == longest + 2
