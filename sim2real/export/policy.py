"""One small interface for a trained policy, wherever it came from.

``load_policy(path)`` returns a ``Policy`` for a run directory (SB3 + torch), an exported ``.onnx``
file (onnxruntime) or an exported ``.npz`` file (numpy alone). Calling it maps an observation, or a
batch of them, to the env's normalised action, deterministically, with observation normalisation
folded in. ``policy.meta`` carries what the deploy loop must check before it moves a real arm: the
env id, the arm-spec fingerprint and the observation layout. Only numpy and the standard library
are imported here, so the robot side stays light.
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.errors import Sim2RealError


class PolicyError(Sim2RealError):
    """A policy file is unusable, or does not fit the arm or the observation it is given."""


@dataclass(frozen=True)
class PolicyMeta:
    """What a policy was trained for; exported files embed it as JSON."""

    env_id: str
    algo: str
    dr: str
    spec_name: str
    spec_fingerprint: str
    obs_shape: tuple[int, ...]
    action_dim: int
    obs_keys: tuple[str, ...] | None = None  # dict observations: flattened in this order
    obs_key_sizes: tuple[int, ...] | None = None
    obs_layout: tuple[dict[str, Any], ...] = ()
    control_hz: float = 20.0
    max_delta_rad: float = 0.1
    source: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str, source: str = "") -> PolicyMeta:
        try:
            d = json.loads(text)
            d["obs_shape"] = tuple(d["obs_shape"])
            for key in ("obs_keys", "obs_key_sizes"):
                if d.get(key) is not None:
                    d[key] = tuple(d[key])
            d["obs_layout"] = tuple(d.get("obs_layout", ()))
            if source:
                d["source"] = source
            return cls(**d)
        except (json.JSONDecodeError, KeyError, TypeError) as exc:
            raise PolicyError(f"policy {source!r}: bad metadata ({exc})") from None

    @classmethod
    def from_run_config(cls, config: Mapping[str, Any], source: str = "") -> PolicyMeta:
        keys = config.get("obs_keys")
        sizes = config.get("obs_key_sizes")
        return cls(
            env_id=str(config["env_id"]),
            algo=str(config["algo"]),
            dr=str(config["dr"]),
            spec_name=str(config.get("spec_name", config["spec"].get("name", ""))),
            spec_fingerprint=str(config["spec_fingerprint"]),
            obs_shape=tuple(config.get("obs_shape", ())),
            action_dim=int(config.get("action_dim", 0)),
            obs_keys=None if keys is None else tuple(keys),
            obs_key_sizes=None if sizes is None else tuple(sizes),
            obs_layout=tuple(config.get("obs_layout", ())),
            control_hz=float(config.get("control_hz", 20.0)),
            max_delta_rad=float(config.get("max_delta_rad", 0.1)),
            source=source,
            extra={  # enough to rebuild the training env from an exported file alone
                "env_kwargs": dict(config.get("env_kwargs", {})),
                "dr_ranges": config.get("dr_ranges"),
                "spec": config["spec"],
                "training_seeds": list(config.get("training_seeds", [])),
            },
        )

    def check_spec(self, fingerprint: str) -> None:
        """Refuse an arm whose spec differs from the one the policy was trained for."""
        if fingerprint != self.spec_fingerprint:
            raise PolicyError(
                f"policy {self.source!r} was trained for arm spec {self.spec_name!r} "
                f"(fingerprint {self.spec_fingerprint}), not for fingerprint {fingerprint}"
            )

    def check_layout(self, names_sizes: list[tuple[str, int]]) -> None:
        """Refuse an observation layout other than the policy's: same size is not same meaning."""
        trained = [(str(f["name"]), int(f["stop"]) - int(f["start"])) for f in self.obs_layout]
        if trained and trained != names_sizes:
            raise PolicyError(
                f"policy {self.source!r} was trained on observation layout "
                f"{[n for n, _ in trained]}; this version builds {[n for n, _ in names_sizes]} "
                "(retrain the policy)"
            )

    @property
    def flat_obs_dim(self) -> int:
        return int(np.prod(self.obs_shape))


class Policy(ABC):
    """``policy(obs) -> action``: one observation (or a batch) in, normalised action(s) out."""

    meta: PolicyMeta

    def __call__(self, obs: np.ndarray | Mapping[str, np.ndarray]) -> np.ndarray:
        batch, single = self._as_batch(obs)
        actions = self._act(batch)
        return actions[0] if single else actions

    @abstractmethod
    def _act(self, batch: np.ndarray) -> np.ndarray:
        """(n, *obs_shape) float32 → (n, action_dim) float32."""

    def _as_batch(self, obs: np.ndarray | Mapping[str, np.ndarray]) -> tuple[np.ndarray, bool]:
        m = self.meta
        if isinstance(obs, Mapping):
            if m.obs_keys is None:
                raise PolicyError(f"policy {m.source!r} takes an array observation, got a dict")
            missing = [k for k in m.obs_keys if k not in obs]
            if missing:
                raise PolicyError(f"observation lacks keys {missing}; expected {list(m.obs_keys)}")
            parts = [np.asarray(obs[k], dtype=np.float32) for k in m.obs_keys]
            single = parts[0].ndim == 1
            flat = np.concatenate([p.reshape(1 if single else len(p), -1) for p in parts], axis=1)
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


# ---- loading ----------------------------------------------------------------------------------
def load_policy(path: str | Path) -> Policy:
    """A run directory, an exported ``.onnx`` or an exported ``.npz`` policy (the format registry
    is ``sim2real.export.formats``; it imports this module, hence the late import)."""
    from sim2real.export.formats import load_policy as load

    return load(path)
