"""Import robosuite once, quietly: every robosuite-facing module goes through ``import_robosuite``.

robosuite 1.5.2 logs three warnings on import (no private macro file; the optional
robosuite_models and mink packages are missing) and one INFO line per env it builds. None of them
is actionable for our users, so they are filtered at the ``robosuite_logs`` logger; robosuite's
warnings after import still show.
"""

from __future__ import annotations

import logging
from typing import Any

_LOGGER = "robosuite_logs"


class _BelowLevel(logging.Filter):
    def __init__(self, level: int) -> None:
        super().__init__()
        self.level = level

    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno >= self.level


def import_robosuite() -> Any:
    """The robosuite module (imported on first call, about 1.5 s)."""
    logger = logging.getLogger(_LOGGER)
    during = _BelowLevel(logging.ERROR)
    logger.addFilter(during)
    try:
        import robosuite
    finally:
        logger.removeFilter(during)
    if not any(isinstance(f, _BelowLevel) for f in logger.filters):
        logger.addFilter(_BelowLevel(logging.WARNING))
    return robosuite
