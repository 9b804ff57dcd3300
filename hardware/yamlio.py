"""A strict YAML subset, so the hardware layer runs beside the arm with only numpy and pyserial.

It reads what the project writes: block mappings, block sequences (of scalars or mappings), one-line
flow sequences of scalars, comments, and plain/quoted scalars (int, float, bool, null, str). Anything
else (anchors, multi-line strings, flow mappings, tabs) is refused with the line number, never
guessed. The test suite checks that PyYAML reads every document this module writes identically and
that this module reads PyYAML's output of the same data identically.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from hardware.atomic import atomic_write_text
from hardware.errors import YamlError

_INT_RE = re.compile(r"^[-+]?(0|[1-9][0-9_]*)$")
# Floats exactly as PyYAML resolves them (a dot is required, an exponent needs its sign), so
# that a string PyYAML writes unquoted, such as '1e5' or '0E0', reads back as a string here too.
_FLOAT_RE = re.compile(
    r"^(?:[-+]?[0-9][0-9_]*\.[0-9_]*(?:[eE][-+][0-9]+)?|\.[0-9][0-9_]*(?:[eE][-+][0-9]+)?)$"
)
_INF = {
    f"{sign}.{word}": (-math.inf if sign == "-" else math.inf)
    for sign in ("", "+", "-")
    for word in ("inf", "Inf", "INF")
}
# Words PyYAML (YAML 1.1) reads as booleans: written quoted so PyYAML reads them back as strings.
_YAML11_BOOL = {
    w
    for base in ("yes", "no", "on", "off", "true", "false")
    for w in (base, base.title(), base.upper())
}
_NAN = {".nan", ".NaN", ".NAN"}
_BOOL = {"true": True, "True": True, "TRUE": True, "false": False, "False": False, "FALSE": False}
_NULL = {"null", "Null", "NULL", "~", ""}
_PLAIN_SAFE = re.compile(r"^[A-Za-z_/.][A-Za-z0-9_ ./+()-]*$")


def _strip_comment(text: str) -> str:
    """Drop a trailing ``# comment`` that is outside quotes (``\\"`` does not close a
    double-quoted string; ``''`` inside a single-quoted one closes and reopens it, which is the
    same)."""
    quote = ""
    escaped = False
    for i, ch in enumerate(text):
        if quote:
            if escaped:
                escaped = False
            elif quote == '"' and ch == "\\":
                escaped = True
            elif ch == quote:
                quote = ""
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (i == 0 or text[i - 1] in " \t"):
            return text[:i].rstrip()
    return text.rstrip()


def parse_scalar(token: str, line_no: int = 0) -> Any:
    """One scalar as YAML 1.2 core schema reads it (plus PyYAML's float forms)."""
    tok = token.strip()
    if len(tok) >= 2 and tok[0] == tok[-1] and tok[0] in "'\"":
        body = tok[1:-1]
        if tok[0] == "'":
            return body.replace("''", "'")
        return body.encode("utf-8").decode("unicode_escape")
    if tok in _NULL:
        return None
    if tok in _BOOL:
        return _BOOL[tok]
    if tok in _INF:
        return _INF[tok]
    if tok in _NAN:
        return math.nan
    if _INT_RE.match(tok):
        return int(tok.replace("_", ""))
    if _FLOAT_RE.match(tok) and any(c.isdigit() for c in tok):
        return float(tok.replace("_", ""))
    if tok[0] in "[{&*!|>%@`":
        raise YamlError(f"line {line_no}: unsupported YAML construct {tok!r}")
    return tok


def _split_flow_items(inner: str, text: str, line_no: int) -> list[str]:
    """Split ``a, "b, c", 'd'`` at the commas outside quotes."""
    items: list[str] = []
    current: list[str] = []
    quote = ""
    i = 0
    while i < len(inner):
        ch = inner[i]
        if quote:
            current.append(ch)
            if quote == '"' and ch == "\\" and i + 1 < len(inner):
                current.append(inner[i + 1])
                i += 1
            elif ch == quote:
                if quote == "'" and inner[i + 1 : i + 2] == "'":
                    current.append("'")
                    i += 1
                else:
                    quote = ""
        elif ch in "'\"" and not "".join(current).strip():
            quote = ch
            current.append(ch)
        elif ch in "[]{}":
            raise YamlError(f"line {line_no}: nested flow collections are not supported: {text!r}")
        elif ch == ",":
            items.append("".join(current))
            current = []
        else:
            current.append(ch)
        i += 1
    if quote:
        raise YamlError(f"line {line_no}: unterminated quote in {text!r}")
    items.append("".join(current))
    return items


def _parse_flow_seq(text: str, line_no: int) -> list[Any]:
    inner = text.strip()[1:-1].strip()
    if not inner:
        return []
    return [parse_scalar(part, line_no) for part in _split_flow_items(inner, text, line_no)]


def _value(text: str, line_no: int) -> Any:
    text = text.strip()
    if text.startswith("["):
        if not text.endswith("]"):
            raise YamlError(f"line {line_no}: unterminated flow sequence {text!r}")
        return _parse_flow_seq(text, line_no)
    return parse_scalar(text, line_no)


class _Parser:
    def __init__(self, text: str) -> None:
        self.lines: list[tuple[int, int, str]] = []  # (line_no, indent, content)
        for no, raw in enumerate(text.splitlines(), start=1):
            if "\t" in raw[: len(raw) - len(raw.lstrip())]:
                raise YamlError(f"line {no}: tabs are not allowed for indentation")
            content = _strip_comment(raw)
            if not content.strip() or content.strip() in ("---", "..."):
                continue
            indent = len(content) - len(content.lstrip(" "))
            self.lines.append((no, indent, content.strip()))
        self.pos = 0

    def parse(self) -> Any:
        if not self.lines:
            return None
        result = self._block(self.lines[0][1])
        if self.pos != len(self.lines):
            no, _, content = self.lines[self.pos]
            raise YamlError(f"line {no}: unexpected indentation at {content!r}")
        return result

    def _block(self, indent: int) -> Any:
        _, _, content = self.lines[self.pos]
        if content == "-" or content.startswith("- "):
            return self._seq(indent)
        return self._map(indent)

    def _split_key(self, content: str, no: int) -> tuple[str, str]:
        m = re.match(r"""^("[^"]*"|'[^']*'|[^:#\[\]{}]+?)\s*:(\s+(.*))?$""", content)
        if not m:
            raise YamlError(f"line {no}: expected 'key: value', got {content!r}")
        key = parse_scalar(m.group(1), no)
        return str(key), (m.group(3) or "")

    def _map(self, indent: int) -> dict[str, Any]:
        out: dict[str, Any] = {}
        while self.pos < len(self.lines):
            no, ind, content = self.lines[self.pos]
            if ind < indent:
                break
            if ind > indent:
                raise YamlError(f"line {no}: unexpected indentation at {content!r}")
            if content.startswith("- "):
                raise YamlError(f"line {no}: a list item where a mapping key was expected")
            key, rest = self._split_key(content, no)
            if key in out:
                raise YamlError(f"line {no}: duplicate key {key!r}")
            self.pos += 1
            if rest:
                out[key] = _value(rest, no)
            elif self.pos < len(self.lines) and (
                self.lines[self.pos][1] > indent
                or (self.lines[self.pos][1] == indent and self.lines[self.pos][2].startswith("-"))
            ):
                out[key] = self._block(self.lines[self.pos][1])
            else:
                out[key] = None
        return out

    def _seq(self, indent: int) -> list[Any]:
        out: list[Any] = []
        while self.pos < len(self.lines):
            no, ind, content = self.lines[self.pos]
            if ind < indent or not (content == "-" or content.startswith("- ")):
                if ind > indent:
                    raise YamlError(f"line {no}: unexpected indentation at {content!r}")
                break
            if ind > indent:
                raise YamlError(f"line {no}: unexpected indentation at {content!r}")
            rest = content[1:].strip()
            if not rest:
                self.pos += 1
                out.append(
                    self._block(self.lines[self.pos][1]) if self.pos < len(self.lines) else None
                )
                continue
            if re.match(r"""^("[^"]*"|'[^']*'|[^:#\[\]{}'"]+?)\s*:(\s|$)""", rest):
                # "- key: value" opens a mapping whose keys sit at the column after "- ".
                child_indent = ind + (len(content) - len(rest))
                self.lines[self.pos] = (no, child_indent, rest)
                out.append(self._map(child_indent))
            else:
                self.pos += 1
                out.append(_value(rest, no))
        return out


def loads(text: str) -> Any:
    """Parse a YAML document of the supported subset."""
    return _Parser(text).parse()


def load(path: str | os.PathLike[str]) -> Any:
    """Read and parse a YAML file; errors name the file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise YamlError(f"no such file: {str(p)!r}") from None
    except UnicodeDecodeError as exc:
        raise YamlError(f"{str(p)!r} is not UTF-8 text: {exc.reason}") from None
    try:
        return loads(text)
    except YamlError as exc:
        raise YamlError(f"{p}: {exc}") from None


def format_scalar(value: Any) -> str:
    """A scalar in a form both this module and PyYAML read back to the same value."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return ".nan"
        if math.isinf(value):
            return ".inf" if value > 0 else "-.inf"
        text = repr(value)
        if "e" in text and "." not in text.split("e")[0]:
            mant, exp = text.split("e")
            text = f"{mant}.0e{exp}"  # PyYAML needs a dot in the mantissa to read a float
        return text
    if hasattr(value, "item") and callable(value.item):  # numpy scalar
        return format_scalar(value.item())
    text = str(value)
    if text in _YAML11_BOOL:  # PyYAML would read these plain words as booleans
        return f'"{text}"'
    parsed = parse_scalar(text) if _PLAIN_SAFE.match(text) else None
    if isinstance(parsed, str) and parsed == text and not text.endswith(" "):
        return text
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _dump(value: Any, indent: int, lines: list[str]) -> None:
    pad = " " * indent
    if isinstance(value, Mapping):
        for key, item in value.items():
            k = format_scalar(str(key))
            if (isinstance(item, Mapping) and item) or _is_block_seq(item):
                lines.append(f"{pad}{k}:")
                _dump(item, indent + 2, lines)
            else:
                lines.append(f"{pad}{k}: {_inline(item)}")
    elif isinstance(value, Sequence) and not isinstance(value, str):
        for item in value:
            if isinstance(item, Mapping) and item:
                sub: list[str] = []
                _dump(item, indent + 2, sub)
                sub[0] = f"{pad}- " + sub[0][indent + 2 :]
                lines.extend(sub)
            else:
                lines.append(f"{pad}- {_inline(item)}")
    else:
        lines.append(pad + format_scalar(value))


def _is_block_seq(value: Any) -> bool:
    return (
        isinstance(value, Sequence)
        and not isinstance(value, str)
        and any(isinstance(v, Mapping) and v for v in value)
    )


def _inline(value: Any) -> str:
    if isinstance(value, Mapping):
        if value:
            raise YamlError("a non-empty mapping cannot be written inline")
        return "{}"
    if hasattr(value, "tolist") and callable(value.tolist):  # numpy array
        value = value.tolist()
    if isinstance(value, Sequence) and not isinstance(value, str):
        if any(isinstance(v, (Mapping, list, tuple)) for v in value):
            raise YamlError("nested sequences are outside the supported YAML subset")
        return "[" + ", ".join(format_scalar(v) for v in value) + "]"
    return format_scalar(value)


def dumps(data: Mapping[str, Any], header: str = "") -> str:
    """Serialise a mapping; ``header`` becomes leading comment lines (units, provenance)."""
    lines = [f"# {h}" if h else "#" for h in header.splitlines()] if header else []
    _dump(data, 0, lines)
    return "\n".join(lines) + "\n"


def dump(path: str | os.PathLike[str], data: Mapping[str, Any], header: str = "") -> None:
    """Write a mapping to YAML atomically."""
    atomic_write_text(path, dumps(data, header))
