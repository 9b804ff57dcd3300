"""An SB3 model (with its VecNormalize) as a ``Policy``: the reference every export is checked
against. Reading one from a run directory is the trainer's business
(``sim2real.train.policy_io``), so this package never imports ``train``."""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.export.policy import Policy, PolicyMeta


class TorchPolicy(Policy):
    """SB3 ``predict(deterministic=True)`` on VecNormalize-normalised observations."""

    def __init__(self, model: Any, vecnormalize: Any, meta: PolicyMeta, table: Any) -> None:
        self.model = model
        self.vecnormalize = vecnormalize
        self.meta = meta
        self.table = None if table is None else np.asarray(table, dtype=np.float32)

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
