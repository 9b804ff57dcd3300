"""An SB3 model (with its VecNormalize) as a ``Policy``: the reference every export is checked
against. Reading one from a run directory is the trainer's business
(``sim2real.train.policy_io``), so this package never imports ``train``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from sim2real.export.policy import Policy, PolicyMeta


def env_frame_shape(space: Any) -> tuple[int, ...]:
    """A key of a policy's space in the env's own shape: an image SB3 reads channels first is
    the channels-last frame it transposed (every sim2real pixel env renders channels last)."""
    from stable_baselines3.common.preprocessing import (
        is_image_space,
        is_image_space_channels_first,
    )

    shape = tuple(int(n) for n in space.shape)
    if is_image_space(space) and is_image_space_channels_first(space):
        return (shape[1], shape[2], shape[0])
    return shape


class TorchPolicy(Policy):
    """SB3 ``predict(deterministic=True)`` on VecNormalize-normalised observations."""

    def __init__(self, model: Any, vecnormalize: Any, meta: PolicyMeta, table: Any) -> None:
        self.model = model
        self.vecnormalize = vecnormalize
        self.meta = meta
        self.table = None if table is None else np.asarray(table, dtype=np.float32)

    @property
    def key_shapes(self) -> dict[str, tuple[int, ...]]:
        """Each key of a dict observation in the env's own shape (empty for an array one).
        Records written before ``obs_key_shapes`` take the model's space, and an image SB3 read
        channels first is taken as the channels-last frame it transposed: every sim2real pixel
        env renders channels last."""
        m = self.meta
        if m.obs_keys is None:
            return {}
        if m.obs_key_shapes is not None:
            return dict(zip(m.obs_keys, m.obs_key_shapes, strict=True))
        space = self.model.observation_space.spaces
        return {key: env_frame_shape(space[key]) for key in m.obs_keys}

    def unflatten(self, batch: np.ndarray) -> Any:
        m = self.meta
        if m.obs_keys is None or m.obs_key_sizes is None:
            return batch
        shapes = self.key_shapes
        out, start = {}, 0
        for key, size in zip(m.obs_keys, m.obs_key_sizes, strict=True):
            out[key] = batch[:, start : start + size].reshape(len(batch), *shapes[key])
            start += size
        return out

    def _normalized(self, batch: np.ndarray) -> Any:
        obs = self.unflatten(batch)
        if self.vecnormalize is not None:
            obs = self.vecnormalize.normalize_obs(obs)
        return obs

    def _act(self, batch: np.ndarray) -> np.ndarray:
        action, _ = self.model.predict(self._normalized(batch), deterministic=True)
        if self.table is not None:
            action = self.table[np.asarray(action, dtype=np.int64).reshape(-1)]
        return np.asarray(action, dtype=np.float32).reshape(len(batch), -1)

    def _scores(self, batch: np.ndarray) -> np.ndarray | None:
        """A categorical actor's logits (the raw ``action_net`` output, not the distribution's
        normalised ones) or DQN's Q-values; None for a continuous policy."""
        import torch as th

        policy = self.model.policy
        head = _score_head(policy)
        if head is None:
            return None
        policy.set_training_mode(False)  # no augmentation, as in ``predict``
        obs, _ = policy.obs_to_tensor(self._normalized(batch))
        with th.no_grad():
            scores = head(policy, obs)
        return np.asarray(scores.cpu().numpy(), dtype=np.float32)


def _logits(policy: Any, obs: Any) -> Any:
    from stable_baselines3.common.policies import BaseModel

    # the actor's own extractor: ``ActorCriticPolicy.extract_features`` would run the critic's too
    features = BaseModel.extract_features(policy, obs, policy.pi_features_extractor)
    return policy.action_net(policy.mlp_extractor.forward_actor(features))


def _q_values(policy: Any, obs: Any) -> Any:
    return policy.q_net(obs)


def _score_head(policy: Any) -> Callable[[Any, Any], Any] | None:
    """How ``policy`` computes the scores its deterministic action is the argmax of."""
    from gymnasium import spaces
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.dqn.policies import DQNPolicy

    if isinstance(policy, DQNPolicy):
        return _q_values
    if isinstance(policy, ActorCriticPolicy) and isinstance(policy.action_space, spaces.Discrete):
        return _logits
    return None
