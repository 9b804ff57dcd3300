"""Progress bars where people look: on a terminal, never in CI logs or piped output.

Long commands (train, compare, evaluate, dataset recording, the demo's stages) ask for a bar with
``progress_bar``; it draws only when asked, stdout is a terminal and ``CI`` is unset, so a
``--json`` consumer or a CI log gets clean output.
"""

from __future__ import annotations

import os
import sys
from typing import Any, TextIO


def progress_enabled(requested: bool = True, stream: TextIO | None = None) -> bool:
    """Whether to draw: asked for, ``stream`` (stdout) is a TTY, and not in CI."""
    if not requested or os.environ.get("CI", "").strip().lower() not in ("", "0", "false"):
        return False
    out = sys.stdout if stream is None else stream
    try:
        return bool(out.isatty())
    except (AttributeError, ValueError):  # closed or replaced streams
        return False


def progress_bar(total: int | None, desc: str, unit: str, requested: bool = True) -> Any:
    """A tqdm bar on stderr, disabled (a no-op object with the same methods) when quiet."""
    from tqdm import tqdm

    return tqdm(
        total=total,
        desc=desc,
        unit=unit,
        disable=not progress_enabled(requested),
        dynamic_ncols=True,
        leave=False,
    )
