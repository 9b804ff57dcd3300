"""Image feature extractors for pixel policies, by name (``policy_kwargs.features_extractor``).

SB3's ``NatureCNN`` was sized for 84×84 Atari frames: on a 48×48 image its 8×8/4, 4×4/2 and 3×3/1
convolutions leave a 2×2 map, so *where* a 5-pixel object sits — the whole question in a grasping
task — survives only in channel mixtures. ``keypoint_cnn`` keeps a 12×12 map and reads it with a
spatial soft-argmax (Levine et al., "End-to-end training of deep visuomotor policies", 2016): each
channel becomes the image coordinates of its strongest response, which is what a policy that
servos a gripper onto an object needs. Two coordinate channels (CoordConv) let the convolutions
tell the gripper's position from an object's at the same cost. Its multiply-adds at 48×48 are of
the same order as NatureCNN's, so the CPU budget holds.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import torch as th
from stable_baselines3.common.sb2_compat.rmsprop_tf_like import RMSpropTFLike
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, NatureCNN

from sim2real.errors import ConfigError, UnknownNameError


def _coords(h: int, w: int) -> th.Tensor:
    """(2, h, w) pixel-centre coordinates in [-1, 1]: x along width, y along height."""
    ys = th.linspace(-1.0, 1.0, h)
    xs = th.linspace(-1.0, 1.0, w)
    gy, gx = th.meshgrid(ys, xs, indexing="ij")
    return th.stack((gx, gy))


def soft_argmax(fmap: th.Tensor, map_coords: th.Tensor, temperature: th.Tensor) -> th.Tensor:
    """(n, C, h·w) feature maps → (n, 2C) expected (x, y) of each channel under its softmax."""
    attn = th.softmax(fmap / temperature, dim=-1)
    return th.einsum("nck,dk->ncd", attn, map_coords).flatten(1)


class KeypointCNN(BaseFeaturesExtractor):
    """CoordConv → 3 small convolutions → spatial soft-argmax keypoints + channel max-pool."""

    def __init__(
        self, observation_space: gym.spaces.Box, features_dim: int = 128, channels: int = 32
    ) -> None:
        super().__init__(observation_space, features_dim)
        shape = observation_space.shape
        if shape is None or len(shape) != 3:
            raise ConfigError(f"keypoint_cnn needs a (C, H, W) image space, got shape {shape}")
        c, h, w = shape
        if min(h, w) < 16:
            raise ConfigError(f"keypoint_cnn needs images of at least 16x16, got {h}x{w}")
        self.register_buffer("coords", _coords(h, w), persistent=False)
        half = channels // 2
        self.convs = th.nn.Sequential(
            th.nn.Conv2d(c + 2, half, 3, stride=2, padding=1),
            th.nn.ReLU(),
            th.nn.Conv2d(half, channels, 3, stride=2, padding=1),
            th.nn.ReLU(),
            th.nn.Conv2d(channels, channels, 3, stride=1, padding=1),
        )
        with th.no_grad():
            fh, fw = self.convs(th.zeros(1, c + 2, h, w)).shape[-2:]
        self.register_buffer(
            "map_coords", _coords(int(fh), int(fw)).reshape(2, -1), persistent=False
        )
        # Learned softmax temperature: sharp keypoints late in training, soft ones early.
        self.log_temperature = th.nn.Parameter(th.zeros(()))
        self.head = th.nn.Sequential(th.nn.Linear(3 * channels, features_dim), th.nn.ReLU())

    def forward(self, observations: th.Tensor) -> th.Tensor:
        n = observations.shape[0]
        coords = self.coords.expand(n, -1, -1, -1)  # type: ignore[operator]
        fmap = self.convs(th.cat((observations, coords), dim=1)).flatten(2)  # (n, C, h·w)
        keypoints = soft_argmax(fmap, self.map_coords, th.exp(self.log_temperature))  # type: ignore[arg-type]
        presence = th.relu(fmap).amax(dim=-1)  # (n, C): is the feature in the image at all
        return self.head(th.cat((keypoints, presence), dim=1))


FEATURE_EXTRACTORS: dict[str, type[BaseFeaturesExtractor]] = {
    "nature_cnn": NatureCNN,
    "keypoint_cnn": KeypointCNN,
}


def get_extractor(name: str) -> type[BaseFeaturesExtractor]:
    try:
        return FEATURE_EXTRACTORS[name]
    except KeyError:
        raise UnknownNameError("features_extractor", name, FEATURE_EXTRACTORS) from None


# ``policy_kwargs.optimizer`` → the optimizer class. ``rmsprop_tf_like`` is SB3's TensorFlow-style
# RMSprop (squared-gradient average started at 1, eps inside the root): PyTorch's starts it at 0,
# so its first steps are ~10x the learning rate on every weight, which collapsed A2C's policy on
# Kuka (entropy 1.95 -> 1e-8 nats within 2,560 steps, 2026-11-27; docs/studies/kuka-pixels).
OPTIMIZERS: dict[str, type[th.optim.Optimizer]] = {
    "adam": th.optim.Adam,
    "rmsprop": th.optim.RMSprop,
    "rmsprop_tf_like": RMSpropTFLike,
}


def get_optimizer(name: str) -> type[th.optim.Optimizer]:
    try:
        return OPTIMIZERS[name]
    except KeyError:
        raise UnknownNameError("optimizer", name, OPTIMIZERS) from None


def resolve_policy_kwargs(
    pk: dict[str, Any], shift_px: int = 0, pixel_actor: bool = False
) -> dict[str, Any]:
    """Names in a preset's ``policy_kwargs`` → the classes SB3 takes (``features_extractor``,
    ``optimizer``). With image augmentation or
    an asymmetric policy the named CNN (NatureCNN by default) runs inside ``PixelActorExtractor``."""
    out = dict(pk)
    if "optimizer" in out:
        out["optimizer_class"] = get_optimizer(str(out.pop("optimizer")))
    if shift_px or pixel_actor:
        from sim2real.train.augment import PixelActorExtractor

        base = str(out.pop("features_extractor", "nature_cnn"))
        get_extractor(base)
        out["features_extractor_kwargs"] = {
            "base": base,
            "shift_px": shift_px,
            "base_kwargs": dict(out.get("features_extractor_kwargs") or {}),
        }
        out["features_extractor_class"] = PixelActorExtractor
        # SB3 puts no MLP between its own NatureCNN and the heads (net_arch []). Wrapped, it no
        # longer recognises the CNN and would add a 64-64 MLP, which kept a distilled keypoint
        # student at the label marginal: 18.7 % validation accuracy after 500 Adam steps against
        # 36.9 % without it (2026-11-25, 17k Kuka frames). So the wrapped CNN gets SB3's default.
        out.setdefault("net_arch", [])
    elif "features_extractor" in out:
        out["features_extractor_class"] = get_extractor(str(out.pop("features_extractor")))
    return out
