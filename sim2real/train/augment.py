"""Image augmentation for pixel policies: random shift (DrQ, Kostrikov et al. 2020; RAD, Laskin et
al. 2020), inside the actor's feature extractor.

The shift lives in the extractor, not in a wrapper or a replay buffer, so one mechanism serves
on-policy and off-policy algorithms alike: SB3 puts the policy in training mode for its gradient
updates only (``policy.set_training_mode``), so frames are shifted in every update and never while
acting — rollouts, evaluation and the deployed actor see the frame as the camera gave it, and an
exported actor is the plain CNN. For DQN the target network stays in eval mode (SB3 builds it so),
so TD targets are computed on unshifted next frames: DrQ's K=1, M=1 with a clean target. For PPO
the old log-probabilities come from the unshifted frames of the rollout, as in RAD's PPO.

``PixelActorExtractor`` is also the actor's view in the asymmetric actor-critic: from a ``Dict``
observation it reads the image and any proprioceptive keys, never ``PRIVILEGED_KEY``.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import torch as th
from stable_baselines3.common.preprocessing import get_flattened_obs_dim, is_image_space
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from sim2real.errors import ConfigError
from sim2real.observation import PIXELS_KEY as PIXELS_KEY  # the image of a Dict observation

PRIVILEGED_KEY = "privileged"  # the simulator's state: critics and teachers only
MAX_SHIFT_PX = 16


def random_shift(images: th.Tensor, pad_px: int) -> th.Tensor:
    """(n, C, H, W) float images, each moved by its own integer offset in [-pad_px, pad_px] per
    axis; borders repeat the edge pixels (DrQ's replicate padding + random crop)."""
    if pad_px <= 0:
        return images
    n, c, h, w = images.shape
    padded = th.nn.functional.pad(images, (pad_px, pad_px, pad_px, pad_px), mode="replicate")
    dev = images.device
    oy = th.randint(0, 2 * pad_px + 1, (n, 1), device=dev)
    ox = th.randint(0, 2 * pad_px + 1, (n, 1), device=dev)
    rows = th.arange(h, device=dev)[None, :] + oy  # (n, H)
    cols = th.arange(w, device=dev)[None, :] + ox  # (n, W)
    ni = th.arange(n, device=dev)[:, None, None, None]
    ci = th.arange(c, device=dev)[None, :, None, None]
    return padded[ni, ci, rows[:, None, :, None], cols[:, None, None, :]]


def check_shift_px(value: Any) -> int:
    """The one check of ``augment.random_shift_px`` (config and extractor share it)."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_SHIFT_PX:
        raise ConfigError(
            f"augment.random_shift_px must be an integer in [0, {MAX_SHIFT_PX}], got {value!r}"
        )
    return value


def split_observation_space(
    space: gym.spaces.Space[Any],
) -> tuple[str | None, gym.spaces.Box, tuple[str, ...]]:
    """(image key or None for a bare image space, image space, proprioceptive keys)."""
    if isinstance(space, gym.spaces.Box) and is_image_space(space, check_channels=False):
        return None, space, ()
    if not isinstance(space, gym.spaces.Dict):
        raise ConfigError(f"a pixel actor needs an image or a Dict observation, got {space}")
    images = [k for k, s in space.spaces.items() if is_image_space(s, check_channels=False)]
    if len(images) != 1:
        raise ConfigError(f"a pixel actor needs exactly one image key, got {images or 'none'}")
    extra = tuple(k for k in space.spaces if k not in (images[0], PRIVILEGED_KEY))
    image = space.spaces[images[0]]
    assert isinstance(image, gym.spaces.Box)
    return images[0], image, extra


class PixelActorExtractor(BaseFeaturesExtractor):
    """A named image CNN (``extractors.FEATURE_EXTRACTORS``) on the (randomly shifted, while
    training) image, concatenated with the flattened proprioceptive keys; never the privileged
    key, so nothing the deployed camera cannot see reaches the actor."""

    def __init__(
        self,
        observation_space: gym.spaces.Space[Any],
        base: str = "nature_cnn",
        shift_px: int = 0,
        base_kwargs: dict[str, Any] | None = None,
    ) -> None:
        from sim2real.train.extractors import get_extractor

        key, image, extra = split_observation_space(observation_space)
        cnn = get_extractor(base)(image, **dict(base_kwargs or {}))
        extra_dim = 0
        if extra:
            assert isinstance(observation_space, gym.spaces.Dict)
            extra_dim = sum(get_flattened_obs_dim(observation_space.spaces[k]) for k in extra)
        super().__init__(observation_space, cnn.features_dim + extra_dim)
        self.cnn = cnn
        self.image_key = key
        self.extra_keys = extra
        self.shift_px = check_shift_px(shift_px)

    def forward(self, observations: Any) -> th.Tensor:
        image = observations if self.image_key is None else observations[self.image_key]
        if self.training and self.shift_px:
            image = random_shift(image, self.shift_px)
        features = self.cnn(image)
        if not self.extra_keys:
            return features
        extra = [observations[k].flatten(1) for k in self.extra_keys]
        return th.cat([features, *extra], dim=1)
