"""SB3 policy → op program → ``.onnx`` or ``.npz``; one extractor per SB3 policy family."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import CombinedExtractor, FlattenExtractor
from stable_baselines3.dqn.policies import DQNPolicy
from stable_baselines3.sac.policies import SACPolicy
from stable_baselines3.td3.policies import TD3Policy

from sim2real.export.formats import FORMATS, get_format, load_run_dir
from sim2real.export.policy import PolicyError
from sim2real.export.program import Op
from sim2real.export.torch_policy import TorchPolicy

__all__ = ["FORMATS", "build_program", "export_policy", "export_trained"]


def _np(t: th.Tensor) -> np.ndarray:
    return t.detach().cpu().numpy().astype(np.float32).copy()


def _layers(module: th.nn.Module) -> list[Op]:
    """Linear layers and activations of a (nested) Sequential, in order."""
    if isinstance(module, th.nn.Sequential):
        return [op for child in module for op in _layers(child)]
    if isinstance(module, th.nn.Linear):
        bias = module.bias if module.bias is not None else th.zeros(module.out_features)
        return [{"op": "dense", "weight": _np(module.weight), "bias": _np(bias)}]
    if isinstance(module, th.nn.ReLU):
        return [{"op": "act", "fn": "relu"}]
    if isinstance(module, th.nn.Tanh):
        return [{"op": "act", "fn": "tanh"}]
    if isinstance(module, th.nn.ELU):
        return [{"op": "act", "fn": "elu", "alpha": float(module.alpha)}]
    if isinstance(module, th.nn.LeakyReLU):
        return [{"op": "act", "fn": "leaky_relu", "alpha": float(module.negative_slope)}]
    if isinstance(module, th.nn.Flatten | th.nn.Identity):
        return []
    raise PolicyError(f"cannot export layer {type(module).__name__}: MLP layers only")


def _check_extractor(extractor: th.nn.Module) -> None:
    ok = isinstance(extractor, FlattenExtractor) or (
        isinstance(extractor, CombinedExtractor)
        and all(isinstance(m, th.nn.Flatten) for m in extractor.extractors.values())
    )
    if not ok:
        raise PolicyError(
            f"export supports MLP policies on state or goal observations; this policy uses a "
            f"{type(extractor).__name__} feature extractor (pixels): load its run dir instead"
        )


def _unscale(space: Any) -> Op:
    low, high = space.low.astype(np.float64), space.high.astype(np.float64)
    return {
        "op": "affine",
        "scale": ((high - low) / 2).astype(np.float32),
        "offset": ((high + low) / 2).astype(np.float32),
    }


def _actor_critic(p: ActorCriticPolicy, tp: TorchPolicy) -> list[Op]:
    _check_extractor(p.pi_features_extractor)
    if p.use_sde:
        raise PolicyError("export does not support gSDE policies")
    ops = _layers(p.mlp_extractor.policy_net) + _layers(p.action_net)
    space: Any = p.action_space
    if p.squash_output:
        return [*ops, {"op": "act", "fn": "tanh"}, _unscale(space)]
    low, high = space.low.astype(np.float32), space.high.astype(np.float32)
    return [*ops, {"op": "clip", "low": low, "high": high}]


def _td3(p: TD3Policy, tp: TorchPolicy) -> list[Op]:
    _check_extractor(p.actor.features_extractor)
    return [*_layers(p.actor.mu), _unscale(p.action_space)]


def _sac(p: SACPolicy, tp: TorchPolicy) -> list[Op]:
    actor = p.actor
    _check_extractor(actor.features_extractor)
    if actor.use_sde:
        raise PolicyError("export does not support gSDE policies")
    ops = _layers(actor.latent_pi) + _layers(actor.mu)
    return [*ops, {"op": "act", "fn": "tanh"}, _unscale(p.action_space)]


def _dqn(p: DQNPolicy, tp: TorchPolicy) -> list[Op]:
    _check_extractor(p.q_net.features_extractor)
    if tp.table is None:
        raise PolicyError("a DQN run dir must hold its action_table in config.json")
    return [*_layers(p.q_net.q_net), {"op": "argmax_table", "table": tp.table}]


# Order matters: SACPolicy/TD3Policy/DQNPolicy are not ActorCriticPolicy, but keep it explicit.
EXTRACTORS: tuple[tuple[type, Callable[[Any, TorchPolicy], list[Op]]], ...] = (
    (ActorCriticPolicy, _actor_critic),
    (SACPolicy, _sac),
    (TD3Policy, _td3),
    (DQNPolicy, _dqn),
)


def _normalizer(tp: TorchPolicy) -> list[Op]:
    vn = tp.vecnormalize
    if vn is None or not vn.norm_obs:
        return []
    m = tp.meta
    eps = float(vn.epsilon)
    if m.obs_keys is None:
        rms = vn.obs_rms
        mean, std = rms.mean.reshape(-1), np.sqrt(rms.var.reshape(-1) + eps)
    else:
        means, stds = [], []
        keys = set(vn.norm_obs_keys or [])
        for key, size in zip(m.obs_keys, m.obs_key_sizes or (), strict=True):
            if key in keys:
                rms = vn.obs_rms[key]
                means.append(rms.mean.reshape(-1))
                stds.append(np.sqrt(rms.var.reshape(-1) + eps))
            else:
                means.append(np.zeros(size))
                stds.append(np.ones(size))
        mean, std = np.concatenate(means), np.concatenate(stds)
    return [
        {
            "op": "normalize",
            "mean": mean.astype(np.float64),
            "std": std.astype(np.float64),
            "clip": float(vn.clip_obs),
        }
    ]


def build_program(tp: TorchPolicy) -> list[Op]:
    policy = tp.model.policy
    for cls, extract in EXTRACTORS:
        if isinstance(policy, cls):
            return _normalizer(tp) + extract(policy, tp)
    raise PolicyError(f"cannot export policy class {type(policy).__name__}")


def export_trained(tp: TorchPolicy, fmt: str, out: str | Path, source: str = "") -> Path:
    """Write ``tp``'s deterministic policy (normalisation folded in) as ``fmt`` to ``out``."""
    saver = get_format(fmt).save
    program = build_program(tp)
    meta = replace(tp.meta, exported_from=source, export_format=fmt, source=str(out))
    return saver(out, program, meta)


def export_policy(run_dir: str | Path, fmt: str, out: str | Path) -> Path:
    """Write the run's deterministic policy (normalisation folded in) as ``fmt`` to ``out``."""
    get_format(fmt)  # an unknown format fails before the run is loaded
    tp = load_run_dir(run_dir)
    if not isinstance(tp, TorchPolicy):
        raise PolicyError(f"run dir {str(run_dir)!r} did not load as a torch policy")
    return export_trained(tp, fmt, out, source=str(run_dir))
