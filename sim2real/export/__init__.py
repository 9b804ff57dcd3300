"""Export a trained policy for torch-free inference (ONNX or numpy) and load any policy back.

The robot-side entry point is ``load_policy(path) -> Policy`` (run dir, ``.onnx`` or ``.npz``);
``export_policy(run_dir, fmt, out)`` writes the files. See ``policy.py`` for the interface.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from sim2real.export.policy import Policy, PolicyError, PolicyMeta, load_policy

if TYPE_CHECKING:
    from sim2real.export.exporter import FORMATS, export_policy

__all__ = ["FORMATS", "Policy", "PolicyError", "PolicyMeta", "export_policy", "load_policy"]


def __getattr__(name: str) -> Any:
    if name in ("FORMATS", "export_policy"):  # pulls in torch: only when exporting
        from sim2real.export import exporter

        return getattr(exporter, name)
    raise AttributeError(f"module 'sim2real.export' has no attribute {name!r}")
