"""The actor the control loop runs while a learner trains: a numpy copy of the SB3 actor.

The loop must never wait for torch (its import, its thread pool, a gradient step holding the GIL),
so it runs the actor's few matrix products in numpy. The learner publishes the actor's weights as
one flat float32 vector (``actor_arrays`` flattened in a fixed order); ``NumpyActor.load_flat``
takes a new vector between periods. Observations are normalised with the source run's frozen
VecNormalize statistics (``ObsNormalizer``), as the exported policy normalises them.

Kinds: ``deterministic`` (DDPG and TD3: Linear/ReLU layers, a tanh output) and ``gaussian`` (SAC:
a ReLU trunk, a mean head and a log-std head; the squashed mean acts, a tanh-squashed sample
explores).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim2real.errors import ConfigError

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0  # SB3's SAC clamps the log-std to these


@dataclass(frozen=True)
class ObsNormalizer:
    """VecNormalize's observation transform with frozen statistics (no update on the arm)."""

    mean: np.ndarray
    var: np.ndarray
    clip_obs: float
    epsilon: float

    @classmethod
    def from_stats(cls, stats: Mapping[str, Any] | None) -> ObsNormalizer | None:
        """From ``adapt.checkpoint.vecnormalize_stats`` numbers; None when the run did not
        normalise observations."""
        if stats is None or not stats.get("norm_obs", False):
            return None
        return cls(
            np.asarray(stats["obs_mean"], dtype=np.float64),
            np.asarray(stats["obs_var"], dtype=np.float64),
            float(stats["clip_obs"]),
            float(stats["epsilon"]),
        )

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        norm = (np.asarray(obs, dtype=np.float64) - self.mean) / np.sqrt(self.var + self.epsilon)
        return np.clip(norm, -self.clip_obs, self.clip_obs).astype(np.float32)


def actor_arrays(model: Any) -> tuple[str, list[np.ndarray]]:
    """(kind, [W0, b0, W1, b1, ...]) of an SB3 DDPG/TD3/SAC actor, in the order ``NumpyActor``
    applies them; any layer it cannot run in numpy is a ``ConfigError`` naming it."""
    import torch as th

    actor = model.policy.actor
    arrays: list[np.ndarray] = []

    def linears(seq: Any, final_tanh: bool) -> None:
        mods = list(seq)
        for i, mod in enumerate(mods):
            if isinstance(mod, th.nn.Linear):
                arrays.append(mod.weight.detach().cpu().numpy().astype(np.float32).copy())
                arrays.append(mod.bias.detach().cpu().numpy().astype(np.float32).copy())
            elif isinstance(mod, th.nn.ReLU) or (
                final_tanh and isinstance(mod, th.nn.Tanh) and i == len(mods) - 1
            ):
                continue
            else:
                raise ConfigError(
                    f"the actor has a {type(mod).__name__} layer; the loop's numpy actor runs "
                    "Linear, ReLU and a final Tanh only (train with the default activation)"
                )

    if hasattr(actor, "mu") and isinstance(actor.mu, th.nn.Sequential):  # DDPG, TD3
        linears(actor.mu, final_tanh=True)
        return "deterministic", arrays
    if hasattr(actor, "latent_pi") and hasattr(actor, "log_std"):  # SAC
        if getattr(actor, "use_sde", False):
            raise ConfigError("a SAC actor with gSDE cannot run in the loop's numpy actor")
        linears(actor.latent_pi, final_tanh=False)
        for head in (actor.mu, actor.log_std):
            arrays.append(head.weight.detach().cpu().numpy().astype(np.float32).copy())
            arrays.append(head.bias.detach().cpu().numpy().astype(np.float32).copy())
        return "gaussian", arrays
    raise ConfigError(f"no numpy actor for {type(actor).__name__}")


def flatten(arrays: Sequence[np.ndarray]) -> np.ndarray:
    return np.concatenate([a.reshape(-1) for a in arrays]).astype(np.float32)


class NumpyActor:
    """Inference only: ``act(obs)`` deterministic, ``explore(obs, rng)`` with the algorithm's
    exploration (Gaussian noise for DDPG/TD3, a policy sample for SAC)."""

    def __init__(
        self,
        kind: str,
        shapes: Sequence[tuple[int, ...]],
        flat: np.ndarray,
        normalizer: ObsNormalizer | None,
        noise_std: float = 0.1,
        noise_corr_steps: float = 0.0,
        gripper_noise_std: float | None = None,
    ) -> None:
        if kind not in ("deterministic", "gaussian"):
            raise ConfigError(f"actor kind {kind!r} is not deterministic or gaussian")
        if not (math.isfinite(noise_corr_steps) and noise_corr_steps >= 0):
            raise ConfigError(f"noise correlation {noise_corr_steps!r} steps must be >= 0")
        self.kind, self.shapes = kind, [tuple(s) for s in shapes]
        self.size = int(sum(int(np.prod(s)) for s in self.shapes))
        self.normalizer = normalizer
        self.noise_std = float(noise_std)
        # DDPG/TD3 exploration: Gaussian, white (0 steps) or AR(1) with this correlation time,
        # the last action component (a gripper) with a std of its own where given
        self.noise_rho = math.exp(-1.0 / noise_corr_steps) if noise_corr_steps > 0 else 0.0
        self._fresh_gain = math.sqrt(1.0 - self.noise_rho**2)
        self.gripper_noise_std = gripper_noise_std
        self._noise: np.ndarray | None = None
        self._std: np.ndarray | None = None  # per action component, built on the first explore
        self.arrays: list[np.ndarray] = []
        self.load_flat(flat)

    def load_flat(self, flat: np.ndarray) -> None:
        flat = np.asarray(flat, dtype=np.float32).reshape(-1)
        if flat.size != self.size:
            raise ConfigError(f"actor weights have {flat.size} values, the actor {self.size}")
        out, at = [], 0
        for shape in self.shapes:
            n = int(np.prod(shape))
            out.append(flat[at : at + n].reshape(shape).copy())
            at += n
        self.arrays = out

    def flat(self) -> np.ndarray:
        return flatten(self.arrays)

    def _trunk(self, x: np.ndarray, layers: Sequence[np.ndarray]) -> np.ndarray:
        for i in range(0, len(layers), 2):
            x = layers[i] @ x + layers[i + 1]
            if i + 2 < len(layers):
                x = np.maximum(x, 0.0)
        return x

    def _heads(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        x = self.normalizer(obs) if self.normalizer is not None else np.asarray(obs, np.float32)
        if self.kind == "deterministic":
            return np.tanh(self._trunk(x, self.arrays)), None
        trunk = self.arrays[:-4]
        w_mu, b_mu, w_ls, b_ls = self.arrays[-4:]
        latent = np.maximum(self._trunk(x, trunk), 0.0) if trunk else x
        log_std = np.clip(w_ls @ latent + b_ls, LOG_STD_MIN, LOG_STD_MAX)
        return w_mu @ latent + b_mu, log_std

    def act(self, obs: np.ndarray) -> np.ndarray:
        out, _ = self._heads(obs)
        return np.asarray(out if self.kind == "deterministic" else np.tanh(out), np.float32)

    def reset_noise(self) -> None:
        """A new episode: correlated exploration noise starts afresh."""
        self._noise = None

    def explore(self, obs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        out, log_std = self._heads(obs)
        if log_std is None:
            if self._std is None or self._std.shape != out.shape:
                self._std = np.full(out.shape, self.noise_std)
                if self.gripper_noise_std is not None:
                    self._std[..., -1] = self.gripper_noise_std
            fresh = rng.standard_normal(out.shape)
            if self._noise is None or self.noise_rho == 0.0:
                self._noise = fresh
            else:  # AR(1): unit variance, correlation rho per step
                self._noise = self.noise_rho * self._noise + self._fresh_gain * fresh
            noisy = out + self._std * self._noise
            return np.clip(noisy, -1.0, 1.0).astype(np.float32)
        sample = out + np.exp(log_std) * rng.standard_normal(out.shape)
        return np.tanh(sample).astype(np.float32)
