"""hardware.yamlio: PyYAML reads what it writes identically, it reads what PyYAML reads, and a
bad file fails with one line naming the line and the text there."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from hardware import yamlio
from hardware.errors import YamlError
from hardware.spec import DEFAULT_SPEC_PATH

keys = st.text(alphabet="abcdefghijklmnopqrstuvwxyz_", min_size=1, max_size=8)
scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**12), 10**12),
    st.floats(allow_nan=False, allow_infinity=True, width=64),
    st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126), max_size=12),
)
flat_lists = st.lists(scalars, max_size=5)
leaf = st.one_of(scalars, flat_lists)
mapping = st.recursive(
    st.dictionaries(keys, leaf, min_size=1, max_size=5),
    lambda children: st.dictionaries(
        keys,
        st.one_of(leaf, children, st.lists(children, min_size=1, max_size=3)),
        min_size=1,
        max_size=5,
    ),
    max_leaves=20,
)


@settings(max_examples=120, deadline=None)
@given(data=mapping)
def test_pyyaml_reads_what_yamlio_writes(data: dict[str, Any]) -> None:
    text = yamlio.dumps(data, header="units: rad\nsource: test")
    assert yaml.safe_load(text) == data
    assert yamlio.loads(text) == data


@pytest.mark.parametrize("value", ['" #', '"0 #', ['" #'], 'a\\" # b', "it''s # x"])
def test_an_escaped_quote_does_not_end_a_string_before_a_hash(value: Any) -> None:
    # Found by the property test above: ``"\" #"`` was cut at " #" as if it were a comment.
    text = yamlio.dumps({"_": value})
    assert yaml.safe_load(text) == {"_": value}
    assert yamlio.loads(text) == {"_": value}


@settings(max_examples=120, deadline=None)
@given(data=mapping)
def test_yamlio_reads_what_pyyaml_writes(data: dict[str, Any]) -> None:
    text = yaml.safe_dump(data, default_flow_style=False, sort_keys=False)
    assert yamlio.loads(text) == yaml.safe_load(text)


def test_special_floats_and_strings() -> None:
    data = {
        "nan": math.nan,
        "inf": math.inf,
        "ninf": -math.inf,
        "tiny": 1e-300,
        "s": "true",
        "n": "1.5",
    }
    text = yamlio.dumps(data)
    for parsed in (yaml.safe_load(text), yamlio.loads(text)):
        assert (
            math.isnan(parsed["nan"]) and parsed["inf"] == math.inf and parsed["ninf"] == -math.inf
        )
        assert parsed["tiny"] == 1e-300 and parsed["s"] == "true" and parsed["n"] == "1.5"


def test_the_shipped_spec_reads_the_same_both_ways() -> None:
    text = Path(DEFAULT_SPEC_PATH).read_text()
    assert yamlio.loads(text) == yaml.safe_load(text)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("a: 1\n\tb: 2\n", r"line 2: found character '\\t' .* at 'b: 2'"),
        ("a: 1\na: 2\n", "line 2: duplicate key 'a'"),
        ("a:\n  b: 1\n  b: [2]\n", "line 3: duplicate key 'b'"),
        ("a:\n  b: 1\n    c: 2\n", "line 3: mapping values are not allowed here at 'c: 2'"),
        (
            "a: [1\nb: 2\n",
            r"line 2: .* at 'b: 2' \(while parsing a flow sequence opened on line 1: 'a: \[1'\)",
        ),
        ("a: !!python/object/apply:os.getcwd []\n", "line 1: could not determine a constructor"),
    ],
)
def test_bad_yaml_fails_with_one_line_naming_line_and_text(text: str, message: str) -> None:
    with pytest.raises(YamlError, match=message) as info:
        yamlio.loads(text)
    assert "\n" not in str(info.value)


def test_reads_what_pyyaml_safe_load_reads() -> None:
    """Anchors, flow mappings and block scalars are PyYAML's business now, read as it reads them."""
    text = "a: &x [1, 2]\nb: *x\nc: {d: 1.5, e: on}\nf: |\n  two\n  lines\n"
    assert yamlio.loads(text) == yaml.safe_load(text)
    assert yamlio.loads(text)["c"] == {"d": 1.5, "e": True}


def test_load_names_the_file(tmp_path: Path) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text("a: 1\na: 2\n")
    with pytest.raises(YamlError, match=r"bad.yaml: line 2"):
        yamlio.load(p)
    with pytest.raises(YamlError, match="no such file"):
        yamlio.load(tmp_path / "missing.yaml")
    (tmp_path / "bin.yaml").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(YamlError, match="not UTF-8"):
        yamlio.load(tmp_path / "bin.yaml")


def test_atomic_write_replaces_whole_files(tmp_path: Path) -> None:
    p = tmp_path / "sub" / "x.yaml"
    yamlio.dump(p, {"a": 1})
    yamlio.dump(p, {"a": 2, "b": [1, 2]})
    assert yaml.safe_load(p.read_text()) == {"a": 2, "b": [1, 2]}
    assert [q.name for q in p.parent.iterdir()] == ["x.yaml"]
