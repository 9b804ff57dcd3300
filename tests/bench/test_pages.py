"""The benchmark pages are the records rendered: none is stale, every record says when, where
and from what it was measured, and every shipped policy's card agrees with its benchmark row."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

import pages

REQUIRED = ("metric", "value", "unit", "date", "machine", "load", "commit", "command")


def test_no_generated_page_is_stale() -> None:
    old = [str(p.relative_to(pages.REPO)) for p in pages.stale()]
    assert not old, f"stale: {old}; run `python bench/pages.py` (make docs does)"


def test_every_record_is_stamped() -> None:
    for area, rows in pages.load_records().items():
        assert rows, f"no records for {area}"
        for r in rows:
            missing = [k for k in REQUIRED if k not in r]
            assert not missing, f"{area}: {r['metric']} lacks {missing}"
            assert str(r["date"])[:4].isdigit() and r["commit"], (area, r["metric"])


@pytest.mark.parametrize("name", sorted(pages.cards()))
def test_card_and_benchmark_page_agree(name: str) -> None:
    card = pages.cards()[name]
    newest = {pages.figure_key(r): r for r in pages.current(pages.load_records()["training"])}
    page = (pages.PAGES / "training.md").read_text()
    row = next((ln for ln in page.splitlines() if ln.startswith(f"| `{name}`")), None)
    hint = "re-shipped? run `python bench/pages.py --sync-cards`"
    assert row is not None, f"{name}: no row on docs/benchmarks/training.md ({hint})"
    for metric in pages.SHIPPED_METRICS:
        if metric not in card["figures"]:
            continue
        rec = newest.get((metric, name, "", ""))
        assert rec is not None, f"{name}: no {metric} record ({hint})"
        assert rec["value"] == card["figures"][metric], f"{name} {metric}: record != card ({hint})"
        assert rec.get("ci95") == card["figures"].get(f"{metric}_ci95"), f"{name} {metric} ci95"
        assert pages.value_text(rec) in row, f"{name} {metric}: page row != card"


def test_newest_record_wins_and_keeps_its_presentation() -> None:
    old = {
        "metric": "m",
        "label": "a figure",
        "table": "T",
        "value": 1,
        "unit": "ms",
        "date": "2026-11-01",
        "commit": "aaa",
        "machine": "x",
        "load": 1,
        "command": "c",
    }
    new = {
        "metric": "m",
        "value": 2,
        "unit": "ms",
        "date": "2026-11-02T10:00:00Z",
        "commit": "bbb",
        "machine": "x",
        "load": 1,
        "command": "c",
    }  # a bench's own line
    other = {**old, "policy": "p", "value": 3}
    rows = pages.current([old, new, other])
    assert [r["value"] for r in rows] == [2, 3]
    assert rows[0]["label"] == "a figure" and rows[0]["table"] == "T" and rows[0]["commit"] == "bbb"


def test_a_figure_of_an_earlier_policy_says_so() -> None:
    shipped = {"p": {"trained": {"measured": "2026-11-30"}}}
    assert "earlier `p`" in pages._stale_policy({"policy": "p", "date": "2026-11-24"}, shipped)
    assert pages._stale_policy({"policy": "p", "date": "2026-11-30"}, shipped) == ""
    assert "no longer shipped" in pages._stale_policy({"policy": "q", "date": "x"}, shipped)


def test_values_read_as_figures() -> None:
    frac = {"value": 0.915, "unit": "fraction", "ci95": [0.8681, 0.9463]}
    assert pages.value_text(frac) == "91.5 % [86.8, 94.6]"
    assert pages.value_text({"value": 52.0, "unit": "x"}) == "52.0×"
    assert pages.value_text({"value": 15.0, "unit": "ms"}) == "15.0 ms"
    assert pages.value_text({"value": 1.0, "unit": "ratio"}) == "1.00"
    assert pages.value_text({"value": 8494, "unit": "steps/s"}) == "8,494 steps/s"
    assert pages.value_text({"value": 20.0, "unit": "Hz"}) == "20.00 Hz"
    assert json.dumps(pages.value_text({"value": None, "p99_ms": 3.1})) == '"p99_ms 3.1"'
