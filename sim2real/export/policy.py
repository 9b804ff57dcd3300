"""One small interface for a trained policy, wherever it came from.

``load_policy(path)`` returns a ``Policy`` for a run directory (SB3 + torch), an exported ``.onnx``
file (onnxruntime) or an exported ``.npz`` file (numpy alone). Calling it maps an observation, or a
batch of them, to the env's normalised action, deterministically, with observation normalisation
folded in. ``policy.meta`` (a ``RunMeta``, ``sim2real.runmeta``) carries what the deploy loop must
check before it moves a real arm: the env id, the arm-spec fingerprint and the observation layout. Only numpy and the standard library
are imported here, so the robot side stays light.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from sim2real.runmeta import MetaError, PolicyError, RunMeta

# Exported policies carry their run's record: one typed, versioned class for both.
PolicyMeta = RunMeta


def meta_from_json(text: str, source: str) -> RunMeta:
    """The metadata a policy file embeds; an unreadable record is a one-line ``PolicyError``."""
    try:
        return RunMeta.from_json(text, source=source)
    except MetaError as exc:
        raise PolicyError(str(exc)) from None


class Policy(ABC):
    """``policy(obs) -> action``: one observation (or a batch) in, normalised action(s) out."""

    meta: PolicyMeta

    def __call__(self, obs: np.ndarray | Mapping[str, np.ndarray]) -> np.ndarray:
        batch, single = self._as_batch(obs)
        actions = self._act(batch)
        return actions[0] if single else actions

    def scores(self, obs: np.ndarray | Mapping[str, np.ndarray]) -> np.ndarray | None:
        """The per-action scores (logits or Q-values) a discrete policy's action is the argmax
        of, or None for a policy without them. Parity checks compare them: equal actions can
        hide drifting scores."""
        batch, single = self._as_batch(obs)
        out = self._scores(batch)
        if out is None:
            return None
        return out[0] if single else out

    @abstractmethod
    def _act(self, batch: np.ndarray) -> np.ndarray:
        """(n, *obs_shape) float32 → (n, action_dim) float32."""

    def _scores(self, batch: np.ndarray) -> np.ndarray | None:
        """(n, *obs_shape) → (n, n_scores) float32; None where the policy has no scores."""
        return None

    def _as_batch(self, obs: np.ndarray | Mapping[str, np.ndarray]) -> tuple[np.ndarray, bool]:
        m = self.meta
        if isinstance(obs, Mapping):
            if m.obs_keys is None:
                raise PolicyError(f"policy {m.source!r} takes an array observation, got a dict")
            missing = [k for k in m.obs_keys if k not in obs]
            if missing:
                raise PolicyError(f"observation lacks keys {missing}; expected {list(m.obs_keys)}")
            parts = [np.asarray(obs[k], dtype=np.float32) for k in m.obs_keys]
            single = _single(parts[0], m, 0)
            n = 1 if single else len(parts[0])
            sizes = m.obs_key_sizes or ()
            for key, part, size in zip(m.obs_keys, parts, sizes, strict=True):
                if part.size != n * size:
                    what = "one observation" if single else f"a batch of {n}"
                    raise PolicyError(
                        f"observation key {key!r} has shape {part.shape}: not {what} of "
                        f"{size} values (policy {m.source!r})"
                    )
            flat = np.concatenate([p.reshape(n, -1) for p in parts], axis=1)
        else:
            arr = np.asarray(obs)
            single = arr.shape == m.obs_shape
            if not single and arr.shape[1:] != m.obs_shape:
                raise PolicyError(
                    f"observation shape {arr.shape} does not match the policy's {m.obs_shape} "
                    f"(env {m.env_id})"
                )
            flat = arr[None] if single else arr
        if not np.all(np.isfinite(flat)):
            raise PolicyError("observation contains NaN or inf")
        return flat, single


def _single(part: np.ndarray, meta: PolicyMeta, i: int) -> bool:
    """Whether a dict observation's key ``i`` holds one observation, not a batch: its own shape
    (an image is (H, W, C), not (n, H, W, C)), or, in a record that predates the shapes, its
    size, with a leading axis of one read as a batch of one."""
    if meta.obs_key_shapes is not None:
        return part.shape == tuple(meta.obs_key_shapes[i])
    size = (meta.obs_key_sizes or ())[i]
    return part.size == size and not (part.ndim >= 2 and part.shape[0] == 1)


# ---- loading ----------------------------------------------------------------------------------
def load_policy(path: str | Path) -> Policy:
    """A run directory, an exported ``.onnx`` or an exported ``.npz`` policy (the format registry
    is ``sim2real.export.formats``; it imports this module, hence the late import)."""
    from sim2real.export.formats import load_policy as load

    return load(path)
