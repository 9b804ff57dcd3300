"""Asymmetric actor-critic: the critic sees the simulator's privileged state, the actor pixels only.

Only the actor is deployed, so in simulation the value function may read what no camera gives
(Pinto et al., "Asymmetric Actor Critic for Image-Based Robot Learning", 2017): object positions
relative to the gripper make an accurate value estimate possible long before the CNN has learned
to see the objects, and the advantage the actor learns from is less noisy. The state enters as the
``PRIVILEGED_KEY`` entry of a ``Dict`` observation that only training builds (``wrappers.
PrivilegedObservation``, from the env's documented ``info`` key). The actor's extractor
(``PixelActorExtractor``) never reads that key, and ``predict`` also accepts the bare image, so
evaluation and deployment build bare envs and call the same policy; the critic is dropped there.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy, BaseModel
from stable_baselines3.common.preprocessing import (
    get_flattened_obs_dim,
    is_image_space,
)
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from sim2real.errors import ConfigError
from sim2real.export.torch_policy import env_frame_shape
from sim2real.train.augment import PIXELS_KEY, PRIVILEGED_KEY, PixelActorExtractor


class PrivilegedCriticExtractor(BaseFeaturesExtractor):
    """MLP on the privileged vector alone, to the actor's feature width (SB3's ``MlpExtractor``
    feeds the policy and value heads from features of one width)."""

    def __init__(
        self, observation_space: gym.spaces.Dict, features_dim: int, net_arch: Sequence[int]
    ) -> None:
        super().__init__(observation_space, features_dim)
        dims = [get_flattened_obs_dim(observation_space.spaces[PRIVILEGED_KEY]), *net_arch]
        layers: list[th.nn.Module] = []
        for a, b in itertools.pairwise(dims):
            layers += [th.nn.Linear(a, b), th.nn.ReLU()]
        layers += [th.nn.Linear(dims[-1], features_dim), th.nn.ReLU()]
        self.net = th.nn.Sequential(*layers)

    def forward(self, observations: dict[str, th.Tensor]) -> th.Tensor:
        return self.net(observations[PRIVILEGED_KEY].flatten(1))


class AsymmetricActorCriticPolicy(ActorCriticPolicy):
    """``ActorCriticPolicy`` with a pixel actor (``PixelActorExtractor``, shift augmentation
    optional) and a critic on ``PRIVILEGED_KEY`` only."""

    def __init__(
        self,
        observation_space: gym.spaces.Space[Any],
        action_space: gym.spaces.Space[Any],
        lr_schedule: Any,
        critic_net_arch: Sequence[int] = (256,),
        aux_dim: int = 0,
        **kwargs: Any,
    ) -> None:
        if (
            not isinstance(observation_space, gym.spaces.Dict)
            or PRIVILEGED_KEY not in observation_space.spaces
            or PIXELS_KEY not in observation_space.spaces
        ):
            raise ConfigError(
                f"the asymmetric policy needs a Dict observation with {PIXELS_KEY!r} and "
                f"{PRIVILEGED_KEY!r} keys, got {observation_space}"
            )
        self.critic_net_arch = tuple(int(n) for n in critic_net_arch)
        if isinstance(aux_dim, bool) or not isinstance(aux_dim, int) or aux_dim < 0:
            raise ConfigError(f"aux_dim must be an integer >= 0, got {aux_dim!r}")
        self.aux_dim = aux_dim
        kwargs.setdefault("features_extractor_class", PixelActorExtractor)
        kwargs["share_features_extractor"] = False
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _build(self, lr_schedule: Any) -> None:
        # The base class made a second actor-type extractor for the critic: replace it before
        # the heads, the orthogonal init and the optimizer are built.
        assert isinstance(self.observation_space, gym.spaces.Dict)
        self.vf_features_extractor = PrivilegedCriticExtractor(
            self.observation_space, self.features_dim, self.critic_net_arch
        )
        # Training-only auxiliary regression from the actor's image features (distillation's
        # teacher inputs); built before the optimizer so it trains, never exported.
        self.aux_head: th.nn.Module | None = (
            th.nn.Linear(self.features_dim, self.aux_dim) if self.aux_dim else None
        )
        super()._build(lr_schedule)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data["critic_net_arch"] = self.critic_net_arch
        data["aux_dim"] = self.aux_dim
        return data

    def actor_features(self, obs: Any) -> th.Tensor:
        """The actor's features alone (``extract_features`` would run the critic's too)."""
        features = BaseModel.extract_features(self, obs, self.pi_features_extractor)
        assert isinstance(features, th.Tensor)
        return features

    def obs_to_tensor(self, observation: Any) -> tuple[Any, bool]:
        """A bare image (what evaluation and deployment have) is the actor's whole input. A
        ``Dict`` one (a frame beside proprioception) may carry its image flattened, as the
        ``Policy`` interface concatenates the keys: it is the env's frame, reshaped here."""
        if not isinstance(observation, dict):
            observation = {PIXELS_KEY: observation}
        else:
            observation = {k: self._frame(k, v) for k, v in observation.items()}
        return super().obs_to_tensor(observation)

    def _frame(self, key: str, value: Any) -> Any:
        """A flat (n, H·W·C) image key back to the env's channel-last (n, H, W, C) frames
        (SB3 then transposes them to the policy's channel-first space); anything else as is."""
        space = self.observation_space[key]  # type: ignore[index]
        arr = np.asarray(value)
        if not is_image_space(space) or arr.ndim > 2 or arr.shape[-1] != math.prod(space.shape):
            return value
        return arr.reshape(-1, *env_frame_shape(space))

    def actor_modules(self) -> dict[str, th.nn.Module]:
        """Everything an exported actor consists of (the critic is not among them)."""
        return {
            "features_extractor": self.pi_features_extractor,
            "policy_net": self.mlp_extractor.policy_net,
            "action_net": self.action_net,
        }
