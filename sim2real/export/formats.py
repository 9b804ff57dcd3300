"""The registry of policy formats: what can be written, what can be read, and by which suffix.

It lives here, not beside the ``Policy`` base class, so the interface does not know its
implementations: adding a format is one entry below. Only light modules are imported (numpy; onnx
and onnxruntime are imported inside the functions that need them). A run directory is read by the
trainer (SB3 and torch); the registry names that loader as a string entry point, resolved only
when a run directory is loaded, so ``export`` never imports ``train`` or ``evaluate``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from sim2real.errors import RunDirError, UnknownNameError
from sim2real.export.onnx_io import OnnxPolicy, save_onnx
from sim2real.export.policy import Policy, PolicyMeta
from sim2real.export.program import NumpyPolicy, Op, save_npz

Saver = Callable[[str | Path, list[Op], PolicyMeta], Path]
RUN_DIR_LOADER = "sim2real.train.policy_io:load_run_policy"  # needs the ``train`` extra


@dataclass(frozen=True)
class PolicyFormat:
    """One exported-policy file format."""

    name: str
    suffix: str  # lower case, with the dot
    save: Saver
    load: Callable[[Path], Policy]
    needs: str  # what loading it imports, for messages


FORMATS: dict[str, PolicyFormat] = {
    f.name: f
    for f in (
        PolicyFormat("onnx", ".onnx", save_onnx, OnnxPolicy.load, "onnxruntime"),
        PolicyFormat("numpy", ".npz", save_npz, NumpyPolicy.load, "numpy"),
    )
}
BY_SUFFIX: dict[str, PolicyFormat] = {f.suffix: f for f in FORMATS.values()}


def get_format(name: str) -> PolicyFormat:
    if name not in FORMATS:
        raise UnknownNameError("export format", name, FORMATS)
    return FORMATS[name]


def load_run_dir(path: str | Path) -> Policy:
    """A run directory's torch policy, through the trainer's loader (``RUN_DIR_LOADER``)."""
    module_name, attr = RUN_DIR_LOADER.split(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise RunDirError(
            f"loading run dir {str(path)!r} needs torch and stable-baselines3 ({exc.name} is "
            "missing): pip install 'sim2real[train]', or load an exported .onnx/.npz policy"
        ) from None
    loader: Callable[[str | Path], Policy] = getattr(module, attr)
    return loader(path)


def load_policy(path: str | Path) -> Policy:
    """A run directory, an exported file of any registered format, or a shipped policy's
    name (``sim2real policies``)."""
    from sim2real.policies import shipped

    p = Path(path)
    if not p.exists() and str(path) in (ships := shipped()):
        p = ships[str(path)].path
    if p.is_dir():
        return load_run_dir(p)
    if not p.exists():
        raise RunDirError(
            f"policy {str(p)!r} does not exist: no run directory, policy file "
            f"({', '.join(sorted(BY_SUFFIX))}) or shipped policy of that name; shipped policies: "
            f"{sorted(shipped()) or 'none'}"
        )
    fmt = BY_SUFFIX.get(p.suffix.lower())
    if fmt is None:
        raise UnknownNameError("policy file type", p.suffix or p.name, [*BY_SUFFIX, "<run dir>"])
    return fmt.load(p)
