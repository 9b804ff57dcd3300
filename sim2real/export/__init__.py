"""Export a trained policy for torch-free inference (ONNX or numpy) and load any policy back.

The robot-side entry point is ``load_policy(path) -> Policy`` (run dir, ``.onnx`` or ``.npz``);
``export_policy(run_dir, fmt, out)`` writes the files. See ``policy.py`` for the interface and
``formats.py`` for the registry of formats. Nothing here imports ``train`` or ``evaluate``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from sim2real.export.formats import FORMATS, PolicyFormat, load_policy
from sim2real.export.policy import Policy, PolicyError, PolicyMeta

if TYPE_CHECKING:
    from sim2real.export.exporter import export_policy

__all__ = [
    "FORMATS",
    "Policy",
    "PolicyError",
    "PolicyFormat",
    "PolicyMeta",
    "export_policy",
    "load_policy",
]


def __getattr__(name: str) -> Any:
    if name == "export_policy":  # pulls in torch: only when exporting
        from sim2real.export import exporter

        return exporter.export_policy
    raise AttributeError(f"module 'sim2real.export' has no attribute {name!r}")
