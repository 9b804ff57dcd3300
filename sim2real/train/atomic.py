"""Atomic file writes for run directories: hardware's writer plus JSON with numpy values.

The writer itself lives in ``hardware.atomic`` (standard library only, for the Pi side).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from hardware.atomic import atomic_write, atomic_write_bytes, atomic_write_text

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_json", "atomic_write_text"]


def atomic_write_json(path: str | Path, obj: Any) -> Path:
    return atomic_write_text(
        path, json.dumps(obj, indent=2, sort_keys=True, default=_jsonable) + "\n"
    )


def _jsonable(value: Any) -> Any:
    """numpy scalars/arrays and paths in configs become plain JSON values."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
