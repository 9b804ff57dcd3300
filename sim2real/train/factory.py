"""Building the (vectorised) environments a run trains on, the same way for train and resume.

Each worker env is ``gym.make(id, dr=DRConfig, spec=ArmSpec, **env_kwargs)``, then the discrete
action wrapper when the algorithm needs one (never for an env whose own actions are ``Discrete``),
then, for an asymmetric critic or a DAgger teacher, ``PrivilegedObservation``, then SB3's ``Monitor`` (one CSV per env and training segment, with the final ``is_success`` and
``distance_m`` of every episode). Image observations are transposed to channel-first here, not by
SB3, so that a ``VecNormalize`` (reward scaling only: images are never normalised) sits outside
the transpose and the frames an off-policy replay buffer stores have the policy's layout.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.preprocessing import is_image_space, is_image_space_channels_first
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecTransposeImage

MONITOR_KEYWORDS: tuple[str, ...] = ("is_success", "distance_m")
VEC_ENV_CLASSES: dict[str, Callable[[list[Callable[[], gym.Env[Any, Any]]]], VecEnv]] = {
    "dummy": DummyVecEnv,
    "subproc": SubprocVecEnv,
}


def make_env(
    env_id: str,
    env_kwargs: Mapping[str, Any],
    action_table: np.ndarray | None = None,
    monitor_path: str | None = None,
    action_rate_penalty: float = 0.0,
    start_curriculum: Mapping[str, Any] | None = None,
    privileged: bool = False,
) -> gym.Env[Any, Any]:
    """One env as training sees it (module-level, so subprocess workers can pickle it)."""
    import sim2real.envs as envs

    env: gym.Env[Any, Any] = envs.make(env_id, **dict(env_kwargs))
    if start_curriculum:
        from sim2real.train.wrappers import StartCurriculum

        env = StartCurriculum(env, start_curriculum.get("held_prob", 0.0))
    if action_rate_penalty > 0:
        from sim2real.train.wrappers import ActionRatePenalty

        env = ActionRatePenalty(env, action_rate_penalty)
    if action_table is not None:
        from sim2real.train.wrappers import DiscreteDeltaActions

        env = DiscreteDeltaActions(env, action_table)
    if privileged:
        from sim2real.train.wrappers import PrivilegedObservation

        env = PrivilegedObservation(env)
    if monitor_path is not None:
        env = Monitor(env, monitor_path, info_keywords=MONITOR_KEYWORDS)
    return env


def build_vec_env(
    env_id: str,
    env_kwargs: Mapping[str, Any],
    seeds: Sequence[int],
    vec_env: str = "dummy",
    action_table: np.ndarray | None = None,
    monitor_prefix: str | None = None,
    action_rate_penalty: float = 0.0,
    start_curriculum: Mapping[str, Any] | None = None,
    privileged: bool = False,
) -> VecEnv:
    """``len(seeds)`` envs; env i resets first with ``seeds[i]`` (seeds must be consecutive)."""
    fns: list[Callable[[], gym.Env[Any, Any]]] = [
        functools.partial(
            make_env,
            env_id,
            dict(env_kwargs),
            action_table,
            None if monitor_prefix is None else f"{monitor_prefix}.{i}",
            action_rate_penalty,
            None if start_curriculum is None else dict(start_curriculum),
            privileged,
        )
        for i in range(len(seeds))
    ]
    if list(seeds) != list(range(seeds[0], seeds[0] + len(seeds))):
        raise ValueError(f"seeds must be consecutive, got {list(seeds)}")
    venv = VEC_ENV_CLASSES[vec_env if len(seeds) > 1 else "dummy"](fns)
    venv.seed(int(seeds[0]))  # SB3 seeds env i with seeds[0] + i at the next reset
    return venv


def policy_for(observation_space: gym.spaces.Space[Any]) -> str:
    """SB3 policy name for an observation space: dict → MultiInput, image → CNN, else MLP."""
    if isinstance(observation_space, gym.spaces.Dict):
        return "MultiInputPolicy"
    if is_image_space(observation_space):
        return "CnnPolicy"
    return "MlpPolicy"


def _needs_transpose(space: gym.spaces.Space[Any]) -> bool:
    if isinstance(space, gym.spaces.Dict):
        return any(_needs_transpose(s) for s in space.spaces.values())
    return is_image_space(space) and not is_image_space_channels_first(space)  # type: ignore[arg-type]


def transpose_images(venv: VecEnv) -> VecEnv:
    """``VecTransposeImage`` where SB3 would add it itself (channel-last image observations)."""
    return VecTransposeImage(venv) if _needs_transpose(venv.observation_space) else venv


def obs_normalization(
    observation_space: gym.spaces.Space[Any], normalize: bool
) -> tuple[bool, list[str] | None]:
    """``(norm_obs, norm_obs_keys)`` for ``VecNormalize``: every non-image part, no image.

    A CNN scales uint8 pixels by 1/255 itself; normalised frames would be float32 (4x the replay
    memory) and per-pixel statistics of a randomised scene mean nothing.
    """
    if not normalize:
        return False, None
    if isinstance(observation_space, gym.spaces.Dict):
        from sim2real.train.augment import PRIVILEGED_KEY

        # The privileged state is left raw too: evaluation and deployment never have it, and a
        # saved VecNormalize must normalise what the actor alone is given.
        keys = [
            k
            for k, s in observation_space.spaces.items()
            if not is_image_space(s) and k != PRIVILEGED_KEY
        ]
        if not keys:
            return False, None
        return True, None if len(keys) == len(observation_space.spaces) else keys
    return not is_image_space(observation_space), None
