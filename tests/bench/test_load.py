"""The benches' ``emit``: every figure stamped (date, machine, load, commit, command) and, when
recording, appended to a records file as one JSON line."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from support import load


def test_emit_stamps_prints_and_records(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "records" / "speed.jsonl"
    row = load.emit_row({"metric": "x_per_s", "value": 3.0, "unit": "1/s"}, record=str(out))
    printed = json.loads(capsys.readouterr().out)
    assert printed == row
    for key in ("date", "machine", "load", "commit", "command"):
        assert key in row, key
    assert row["date"].endswith("Z") and row["machine"].endswith(" cpu")
    assert row["commit"] != ""
    load.emit_row({"metric": "y", "value": 1, "unit": ""}, record=str(out))
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert [r["metric"] for r in lines] == ["x_per_s", "y"]


def test_a_bench_key_wins_over_the_stamp(capsys: pytest.CaptureFixture[str]) -> None:
    row = load.emit("m", 1, "s", machine="the lent GPU machine")
    capsys.readouterr()
    assert row["machine"] == "the lent GPU machine"


def test_record_flag_is_taken_out_of_argv() -> None:
    argv = ["bench/x.py", "--rounds", "2", "--record", "speed"]
    assert load._take_record_flag(argv) == "speed"
    assert argv == ["bench/x.py", "--rounds", "2"]
    argv = ["bench/x.py", "--record=deploy"]
    assert load._take_record_flag(argv) == "deploy" and argv == ["bench/x.py"]
    assert load._take_record_flag(["bench/x.py"]) is None


def test_an_area_names_a_file_under_bench_records() -> None:
    assert load.record_path("speed") == load.RECORDS_DIR / "speed.jsonl"
    assert load.record_path("/tmp/a.jsonl") == Path("/tmp/a.jsonl")
