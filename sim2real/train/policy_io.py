"""A run directory's trained policy, loaded with SB3 and torch: ``load_run_policy(run_dir)``.

``sim2real.export`` finds it through its format registry (``export.formats.RUN_DIR_LOADER``), by
name, so the export package stays below ``train`` and never imports it.
"""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

from sim2real.errors import RunDirError
from sim2real.export.torch_policy import TorchPolicy
from sim2real.runmeta import RunMeta
from sim2real.train.rundir import RunDir

INFERENCE_OBJECTS: dict[str, Any] = {"replay_buffer_class": None, "replay_buffer_kwargs": {}}


def load_model(run_dir: str | Path) -> tuple[Any, Any, RunMeta]:
    """(SB3 model, VecNormalize or None, record) of a run; corrupt files are ``RunDirError``."""
    from sim2real.train.algos import get_algo

    rd = RunDir(run_dir)
    meta = rd.read_meta()
    model_path, vn_path = rd.policy_files()
    algo = get_algo(meta.algo)
    try:
        # Inference needs no replay buffer: HER's would demand an env just to be built.
        model = algo.cls.load(  # type: ignore[attr-defined]
            str(model_path), device="cpu", custom_objects=INFERENCE_OBJECTS
        )
    except Exception as exc:  # zipfile, pickle and torch errors alike
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise RunDirError(
            f"run dir {str(run_dir)!r}: cannot load {model_path.name} ({msg})"
        ) from None
    vn = None
    if vn_path is not None:
        try:
            with vn_path.open("rb") as fh:
                vn = pickle.load(fh)
        except Exception as exc:
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise RunDirError(
                f"run dir {str(run_dir)!r}: cannot load {vn_path.name} ({msg})"
            ) from None
        vn.training = False
        vn.norm_reward = False
    return model, vn, meta


def load_run_policy(run_dir: str | Path) -> TorchPolicy:
    """The run's deterministic policy with observation normalisation, as a ``Policy``."""
    model, vn, meta = load_model(run_dir)
    return TorchPolicy(model, vn, meta, meta.action_table)
