"""SB3 policy → op program → ``.onnx`` or ``.npz``; one extractor per SB3 policy family, one
translation per feature extractor (flattened state, NatureCNN, the keypoint CNN, the pixel actor)
and one action head per action space (Box: clip or unscale; Discrete: argmax)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.preprocessing import is_image_space
from stable_baselines3.common.torch_layers import CombinedExtractor, FlattenExtractor, NatureCNN
from stable_baselines3.dqn.policies import DQNPolicy
from stable_baselines3.sac.policies import SACPolicy
from stable_baselines3.td3.policies import TD3Policy

from sim2real.export.formats import FORMATS, get_format, load_run_dir
from sim2real.export.policy import PolicyError
from sim2real.export.program import IMAGE_LAYOUTS, Op
from sim2real.export.torch_policy import TorchPolicy

__all__ = ["FORMATS", "build_program", "export_policy", "export_trained"]


def _np(t: th.Tensor) -> np.ndarray:
    return t.detach().cpu().numpy().astype(np.float32).copy()


def _layers(module: th.nn.Module) -> list[Op]:
    """Linear and convolution layers and activations of a (nested) Sequential, in order."""
    if isinstance(module, th.nn.Sequential):
        return [op for child in module for op in _layers(child)]
    if isinstance(module, th.nn.Linear):
        bias = module.bias if module.bias is not None else th.zeros(module.out_features)
        return [{"op": "dense", "weight": _np(module.weight), "bias": _np(bias)}]
    if isinstance(module, th.nn.Conv2d):
        return [_conv2d(module)]
    if isinstance(module, th.nn.ReLU):
        return [{"op": "act", "fn": "relu"}]
    if isinstance(module, th.nn.Tanh):
        return [{"op": "act", "fn": "tanh"}]
    if isinstance(module, th.nn.ELU):
        return [{"op": "act", "fn": "elu", "alpha": float(module.alpha)}]
    if isinstance(module, th.nn.LeakyReLU):
        return [{"op": "act", "fn": "leaky_relu", "alpha": float(module.negative_slope)}]
    if isinstance(module, th.nn.Flatten):
        if (module.start_dim, module.end_dim) != (1, -1):
            raise PolicyError(f"cannot export {module}: only Flatten(1, -1)")
        return [{"op": "flatten"}]
    if isinstance(module, th.nn.Identity):
        return []
    raise PolicyError(
        f"cannot export layer {type(module).__name__}: Linear, Conv2d, Flatten and activations only"
    )


def _conv2d(m: th.nn.Conv2d) -> Op:
    padding = m.padding
    if (
        isinstance(padding, str)
        or m.padding_mode != "zeros"
        or m.groups != 1
        or tuple(m.dilation) != (1, 1)
    ):
        raise PolicyError(f"cannot export {m}: only integer zero padding, groups 1 and dilation 1")
    bias = m.bias if m.bias is not None else th.zeros(m.out_channels)
    return {
        "op": "conv2d",
        "weight": _np(m.weight),
        "bias": _np(bias),
        "stride": [int(v) for v in m.stride],
        "padding": [int(v) for v in padding],
    }


# ---- feature extractors: observation → features ---------------------------------------------
@dataclass(frozen=True)
class Pixels:
    """The exported program's input (the flat observation of ``obs_shape``) and SB3's image
    preprocessing: channels-last frames are transposed, uint8 values divided by 255. A dict
    observation's keys lie side by side in it (``keys``: key → its columns and own shape), and
    ``normalize(keys)`` gives the VecNormalize ops for those keys' columns alone."""

    obs_shape: tuple[int, ...]
    divisor: float
    keys: Mapping[str, tuple[int, int, tuple[int, ...]]]
    normalize: Callable[[tuple[str, ...]], list[Op]]

    def image_op(self, space: Any, shape: tuple[int, ...] | None = None) -> Op:
        """The ``image`` op that turns the observation (or the part of it of ``shape``) into
        the (C, H, W) image ``space``."""
        c, h, w = (int(n) for n in space.shape)
        own = self.obs_shape if shape is None else shape
        for name, layout in IMAGE_LAYOUTS.items():
            if layout.shape((c, h, w)) == own:
                return {"op": "image", "layout": name, "shape": [c, h, w], "divisor": self.divisor}
        raise PolicyError(
            f"the policy's observation shape {own} is not the {(c, h, w)} image its "
            "CNN reads, channels first or last"
        )

    def columns(self, key: str) -> tuple[int, int, tuple[int, ...]]:
        """(start, stop, own shape) of a key the policy reads: a key its record lacks would
        otherwise be read from the wrong columns."""
        if key not in self.keys:
            raise PolicyError(
                f"the policy reads key {key!r}, not among its record's {list(self.keys)}"
            )
        return self.keys[key]


FeatureOps = Callable[[Any, Pixels], list[Op]]


def _flatten_extractor(m: FlattenExtractor, pixels: Pixels) -> list[Op]:
    if is_image_space(m._observation_space):  # an MLP on pixels: SB3 still scales them
        return [pixels.image_op(m._observation_space), {"op": "flatten"}]
    return []  # the program's input is the flat observation already


def _combined(m: CombinedExtractor, pixels: Pixels) -> list[Op]:
    others = sorted(k for k, e in m.extractors.items() if not isinstance(e, th.nn.Flatten))
    if others:
        raise PolicyError(
            f"cannot export a CombinedExtractor whose keys {others} are not flattened (an image "
            "beside other keys): train the actor with a pixel extractor on the image alone"
        )
    return []


def _nature_cnn(m: NatureCNN, pixels: Pixels) -> list[Op]:
    return [pixels.image_op(m._observation_space), *_layers(m.cnn), *_layers(m.linear)]


def _keypoint_cnn(m: Any, pixels: Pixels) -> list[Op]:
    """``sim2real.train.extractors.KeypointCNN.forward``, op by op."""
    return [
        pixels.image_op(m._observation_space),
        {"op": "coord_concat", "coords": _np(m.coords)},
        *_layers(m.convs),
        {
            "op": "keypoints",
            "map_coords": _np(m.map_coords),
            # torch's own exp: numpy and ONNX divide by the very float32 the policy does
            "temperature": _np(th.exp(m.log_temperature)),
        },
        *_layers(m.head),
    ]


def _pixel_actor(m: Any, pixels: Pixels) -> list[Op]:
    """``sim2real.train.augment.PixelActorExtractor``: its CNN (the random shift runs only in
    training mode), then its proprioceptive keys flattened beside the features. A dict input is
    kept in slot ``obs``; the keys beside the image, normalised as VecNormalize did, in slot
    ``extra``, so the image never passes through the normaliser's clip."""
    if not m.extra_keys:
        return _features(m.cnn, pixels)
    start, stop, shape = pixels.columns(m.image_key)
    ops: list[Op] = [{"op": "store", "name": "obs"}]
    width = 0
    for i, key in enumerate(m.extra_keys):
        k_start, k_stop, _ = pixels.columns(key)
        kind = "append" if i else "load"
        ops.append({"op": kind, "name": "obs", "start": k_start, "stop": k_stop})
        width += k_stop - k_start
    ops += pixels.normalize(tuple(m.extra_keys))
    ops += [
        {"op": "store", "name": "extra"},
        {"op": "load", "name": "obs", "start": start, "stop": stop},
    ]
    image = replace(pixels, obs_shape=shape, keys={})
    return [
        *ops,
        *_features(m.cnn, image),
        {"op": "append", "name": "extra", "start": 0, "stop": width},
    ]


def _qualname(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


# Extractor class (exact, by qualified name: two live in ``sim2real.train``, which this package
# never imports) → its ops. A subclass is not matched: its forward may differ.
FEATURES: dict[str, FeatureOps] = {
    _qualname(FlattenExtractor): _flatten_extractor,
    _qualname(CombinedExtractor): _combined,
    _qualname(NatureCNN): _nature_cnn,
    "sim2real.train.extractors.KeypointCNN": _keypoint_cnn,
    "sim2real.train.augment.PixelActorExtractor": _pixel_actor,
}


def _features(extractor: th.nn.Module, pixels: Pixels) -> list[Op]:
    translate = FEATURES.get(_qualname(type(extractor)))
    if translate is None:
        names = sorted(k.rsplit(".", 1)[-1] for k in FEATURES)
        raise PolicyError(
            f"cannot export a {type(extractor).__name__} feature extractor; exportable: {names}"
        )
    return translate(extractor, pixels)


def _extract(policy: Any, extractor: th.nn.Module, tp: TorchPolicy) -> list[Op]:
    divisor = 255.0 if policy.normalize_images else 1.0
    keys, start, shapes = {}, 0, tp.key_shapes
    for key, size in zip(tp.meta.obs_keys or (), tp.meta.obs_key_sizes or (), strict=True):
        keys[key] = (start, start + size, shapes[key])
        start += size
    pixels = Pixels(tuple(tp.meta.obs_shape), divisor, keys, lambda ks: _normalizer(tp, ks))
    return _features(extractor, pixels)


# ---- action heads: features → the env's action ----------------------------------------------
def _unscale(space: Any) -> Op:
    low, high = space.low.astype(np.float64), space.high.astype(np.float64)
    return {
        "op": "affine",
        "scale": ((high - low) / 2).astype(np.float32),
        "offset": ((high + low) / 2).astype(np.float32),
    }


def _box_head(p: ActorCriticPolicy) -> list[Op]:
    space: Any = p.action_space
    if p.squash_output:
        return [{"op": "act", "fn": "tanh"}, _unscale(space)]
    low, high = space.low.astype(np.float32), space.high.astype(np.float32)
    return [{"op": "clip", "low": low, "high": high}]


def _discrete_head(p: ActorCriticPolicy) -> list[Op]:
    return [{"op": "argmax"}]  # the deterministic action: the mode of the categorical


# Action space type → the ops after ``action_net`` (the mean or the logits).
ACTION_HEADS: dict[type, Callable[[ActorCriticPolicy], list[Op]]] = {
    spaces.Box: _box_head,
    spaces.Discrete: _discrete_head,
}


def _actor_critic(p: ActorCriticPolicy, tp: TorchPolicy) -> list[Op]:
    if p.use_sde:
        raise PolicyError("export does not support gSDE policies")
    head = ACTION_HEADS.get(type(p.action_space))
    if head is None:
        raise PolicyError(
            f"cannot export a {type(p.action_space).__name__} action space; exportable: "
            f"{sorted(t.__name__ for t in ACTION_HEADS)}"
        )
    ops = _extract(p, p.pi_features_extractor, tp)
    ops += _layers(p.mlp_extractor.policy_net) + _layers(p.action_net)
    return ops + head(p)


def _td3(p: TD3Policy, tp: TorchPolicy) -> list[Op]:
    ops = _extract(p, p.actor.features_extractor, tp)
    return [*ops, *_layers(p.actor.mu), _unscale(p.action_space)]


def _sac(p: SACPolicy, tp: TorchPolicy) -> list[Op]:
    actor = p.actor
    if actor.use_sde:
        raise PolicyError("export does not support gSDE policies")
    ops = _extract(p, actor.features_extractor, tp)
    ops += _layers(actor.latent_pi) + _layers(actor.mu)
    return [*ops, {"op": "act", "fn": "tanh"}, _unscale(p.action_space)]


def _dqn(p: DQNPolicy, tp: TorchPolicy) -> list[Op]:
    ops = _extract(p, p.q_net.features_extractor, tp) + _layers(p.q_net.q_net)
    if tp.table is not None:  # a Box env: Q-values index the run's action table
        return [*ops, {"op": "argmax_table", "table": tp.table}]
    if isinstance(p.action_space, spaces.Discrete):  # the env's own discrete actions
        return [*ops, {"op": "argmax"}]
    raise PolicyError("a DQN run dir on a Box env must hold its action_table in config.json")


# Order matters: SACPolicy/TD3Policy/DQNPolicy are not ActorCriticPolicy, but keep it explicit.
EXTRACTORS: tuple[tuple[type, Callable[[Any, TorchPolicy], list[Op]]], ...] = (
    (ActorCriticPolicy, _actor_critic),
    (SACPolicy, _sac),
    (TD3Policy, _td3),
    (DQNPolicy, _dqn),
)


def _normalizer(tp: TorchPolicy, only: tuple[str, ...] | None = None) -> list[Op]:
    """VecNormalize as one ``normalize`` op: over the whole flat observation, or over the
    columns of the keys ``only`` (in that order) where a program reads them apart."""
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
        sizes = dict(zip(m.obs_keys, m.obs_key_sizes or (), strict=True))
        raw = sorted(set(only or ()) - keys)
        if raw:  # the op's clip would touch them, where VecNormalize passes them through
            raise PolicyError(
                f"cannot export keys {raw} beside an image that VecNormalize leaves raw"
            )
        for key in m.obs_keys if only is None else only:
            size = sizes[key]
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
    """The policy's ops, VecNormalize first, unless the program reads its input by parts
    (it begins with a ``store``) and has normalised the parts that need it itself."""
    policy = tp.model.policy
    for cls, extract in EXTRACTORS:
        if isinstance(policy, cls):
            ops = extract(policy, tp)
            if ops and ops[0]["op"] == "store":
                return ops
            return _normalizer(tp) + ops
    raise PolicyError(f"cannot export policy class {type(policy).__name__}")


def export_trained(tp: TorchPolicy, fmt: str, out: str | Path, source: str = "") -> Path:
    """Write ``tp``'s deterministic policy (normalisation folded in) as ``fmt`` to ``out``."""
    saver = get_format(fmt).save
    program = build_program(tp)
    meta = replace(tp.meta, exported_from=source, export_format=fmt, source=str(out))
    if meta.obs_keys is not None:  # each key's own shape, also where the run's record predates it
        shapes = tp.key_shapes
        meta = replace(meta, obs_key_shapes=tuple(shapes[k] for k in meta.obs_keys))
    return saver(out, program, meta)


def export_policy(run_dir: str | Path, fmt: str, out: str | Path) -> Path:
    """Write the run's deterministic policy (normalisation folded in) as ``fmt`` to ``out``."""
    get_format(fmt)  # an unknown format fails before the run is loaded
    tp = load_run_dir(run_dir)
    if not isinstance(tp, TorchPolicy):
        raise PolicyError(f"run dir {str(run_dir)!r} did not load as a torch policy")
    return export_trained(tp, fmt, out, source=str(run_dir))
