"""A run directory's SB3 model as a ``Policy``: the reference every export is checked against."""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.errors import RunDirError
from sim2real.export.policy import Policy, PolicyMeta
from sim2real.train.rundir import RunDir

INFERENCE_OBJECTS: dict[str, Any] = {"replay_buffer_class": None, "replay_buffer_kwargs": {}}


def load_model(run_dir: str | Path) -> tuple[Any, Any, dict[str, Any]]:
    """(SB3 model, VecNormalize or None, config) of a run; corrupt files are ``RunDirError``."""
    from sim2real.train.algos import get_algo

    rd = RunDir(run_dir)
    config = rd.read_config()
    model_path, vn_path = rd.policy_files()
    algo = get_algo(str(config["algo"]))
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
    return model, vn, config


class TorchPolicy(Policy):
    """SB3 ``predict(deterministic=True)`` on VecNormalize-normalised observations."""

    def __init__(self, model: Any, vecnormalize: Any, meta: PolicyMeta, table: Any) -> None:
        self.model = model
        self.vecnormalize = vecnormalize
        self.meta = meta
        self.table = None if table is None else np.asarray(table, dtype=np.float32)

    @classmethod
    def from_run_dir(cls, run_dir: str | Path) -> TorchPolicy:
        model, vn, config = load_model(run_dir)
        meta = PolicyMeta.from_run_config(config, source=str(run_dir))
        return cls(model, vn, meta, config.get("action_table"))

    def unflatten(self, batch: np.ndarray) -> Any:
        m = self.meta
        if m.obs_keys is None or m.obs_key_sizes is None:
            return batch
        out, start = {}, 0
        for key, size in zip(m.obs_keys, m.obs_key_sizes, strict=True):
            out[key] = batch[:, start : start + size]
            start += size
        return out

    def _act(self, batch: np.ndarray) -> np.ndarray:
        obs = self.unflatten(batch)
        if self.vecnormalize is not None:
            obs = self.vecnormalize.normalize_obs(obs)
        action, _ = self.model.predict(obs, deterministic=True)
        if self.table is not None:
            action = self.table[np.asarray(action, dtype=np.int64).reshape(-1)]
        return np.asarray(action, dtype=np.float32).reshape(len(batch), -1)
