"""Atomic file writes for the hardware layer: the project's one writer, ``s2r_common.atomic``
(shared with ``calibration``, which may not import ``hardware``)."""

from s2r_common.atomic import atomic_write, atomic_write_bytes, atomic_write_text

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text"]
