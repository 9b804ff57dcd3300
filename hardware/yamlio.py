"""YAML for the hardware layer: PyYAML's safe loader in, a small deterministic writer out.

Reading is ``yaml.safe_load`` with two additions the arm's files need: a duplicate key is an error
(PyYAML keeps the last one silently, which would hide a typo in a spec), and every error is one
line naming the file, the line and the text there. Writing stays here rather than
``yaml.safe_dump`` because its bytes are the spec fingerprint (``ArmSpec.fingerprint``) that
exported policies carry: flow lists of numbers, header comments, and scalars quoted exactly when
PyYAML would otherwise read them back as something else (its own resolver decides).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Hashable, Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from hardware.atomic import atomic_write_text
from hardware.errors import YamlError

_STR_TAG = "tag:yaml.org,2002:str"
_RESOLVER = yaml.resolver.Resolver()
# Strings the writer may leave unquoted (then only if PyYAML resolves them as strings).
_PLAIN_SAFE = re.compile(r"^[A-Za-z_/.][A-Za-z0-9_ ./+()-]*$")


class _Loader(yaml.SafeLoader):
    """``SafeLoader`` that refuses duplicate keys."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        self.flatten_mapping(node)
        seen: set[Hashable] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if isinstance(key, Hashable):
                if key in seen:
                    raise YamlError(f"line {key_node.start_mark.line + 1}: duplicate key {key!r}")
                seen.add(key)
        return super().construct_mapping(node, deep=deep)


def _line(text: str, index: int) -> str:
    lines = text.splitlines()
    return lines[index].strip() if 0 <= index < len(lines) else ""


def loads(text: str) -> Any:
    """Parse one YAML document (PyYAML safe load, duplicate keys refused)."""
    try:
        return yaml.load(text, Loader=_Loader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}: " if mark is not None else ""
        msg = f"{where}{exc.problem or exc.context}"
        if "'\\t'" in msg:
            msg += " (tabs are not allowed for indentation)"
        if mark is not None:
            msg += f" at {_line(text, mark.line)!r}"
        cm = exc.context_mark
        if (
            exc.context
            and exc.problem
            and cm is not None
            and (mark is None or cm.line != mark.line)
        ):
            msg += f" ({exc.context} opened on line {cm.line + 1}: {_line(text, cm.line)!r})"
        raise YamlError(msg.replace("\n", " ").replace("\t", "\\t")) from None
    except yaml.YAMLError as exc:
        raise YamlError(" ".join(str(exc).split())) from None


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


def _reads_back_as_str(text: str) -> bool:
    """Whether PyYAML (YAML 1.1 words such as ``on`` included) reads plain ``text`` as a str."""
    return _RESOLVER.resolve(yaml.ScalarNode, text, (True, False)) == _STR_TAG


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
    if _PLAIN_SAFE.match(text) and not text.endswith(" ") and _reads_back_as_str(text):
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
