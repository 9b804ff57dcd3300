"""A shipped *state* policy as a privileged DAgger teacher for a pixel student (``distill``'s
``pick_ppo`` and ``pick_ddpg``).

A pixel env's ``privileged_state`` ends with the observation the same env in ``obs_mode="state"``
gives, through the same sensor models (``Arm3Env.privileged_state``); the teacher runs the shipped
policy on that tail, deterministically. Its labels are right only where the env acts as the one
the policy was trained in (its task, step size, control rate, safety filter, arm spec): a
mismatch fails when the teacher is bound to an env (``StatePolicyTeacher.check_env``), and a
privileged vector of the wrong length fails at the first label, never a silent mislabel.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from sim2real.errors import ConfigError

if TYPE_CHECKING:
    from sim2real.export.policy import Policy
    from sim2real.observation import ActionDecoder

# Env kwargs that change what a state policy observes or what its action does. The rest (the DR
# preset, the frame's size and camera, proprio, the reward, the success threshold, the episode
# length) shape only the student's observation or how an episode is judged.
ACTING_KWARGS: tuple[str, ...] = (
    "task",
    "control_hz",
    "max_delta_rad",
    "safety_filter",
    "target_stand",
)


@functools.cache
def shipped_policy(name: str) -> Policy:
    """A shipped policy, loaded once per process (a saved model stores only the teacher name)."""
    from sim2real.export import load_policy

    return load_policy(name)


@functools.cache
def _env_defaults() -> dict[str, Any]:
    from sim2real.envs.base import Arm3Env

    params = inspect.signature(Arm3Env.__init__).parameters
    return {k: p.default for k, p in params.items() if p.default is not inspect.Parameter.empty}


@dataclass(frozen=True)
class StatePolicyTeacher:
    """The shipped state policy ``policy_name`` acting on the privileged state's tail.

    ``action``: its deterministic action, clipped to the env's [-1, 1] Box. ``inputs`` (the
    auxiliary target): the tool and the task's first point (pick: the cube), in 0.1 m units."""

    policy_name: str
    decoder: ActionDecoder | None = None
    _policy: Policy = field(init=False, repr=False)
    _start: int = field(init=False, repr=False)
    _size: int = field(init=False, repr=False)
    _tool: int = field(init=False, repr=False)

    def __post_init__(self) -> None:
        from hardware.spec import load_spec
        from sim2real.envs import TASKS
        from sim2real.envs.base import privileged_true_size
        from sim2real.observation import ActionDecoder

        policy = shipped_policy(self.policy_name)
        meta = policy.meta
        task = TASKS.get(meta.task)
        if task is None or meta.obs_keys is not None or len(meta.obs_shape) != 1:
            raise ConfigError(
                f"teacher policy {self.policy_name!r} is not a state policy of an arm task "
                f"(env {meta.env_id}, obs {meta.obs_shape})"
            )
        decoder = self.decoder or ActionDecoder(
            load_spec(), meta.max_delta_rad, use_gripper=task.uses_gripper
        )
        spec = decoder.spec
        if spec.fingerprint() != meta.spec_fingerprint:
            raise ConfigError(
                f"teacher policy {self.policy_name!r} was trained on arm spec "
                f"{meta.spec_name!r} ({meta.spec_fingerprint}); the env's is {spec.name!r} "
                f"({spec.fingerprint()})"
            )
        if decoder.n_actions != meta.action_dim:
            raise ConfigError(
                f"teacher policy {self.policy_name!r} acts in {meta.action_dim} dimensions; the "
                f"env's action has {decoder.n_actions}"
            )
        start = privileged_true_size(spec, task)
        object.__setattr__(self, "_policy", policy)
        object.__setattr__(self, "_start", start)
        object.__setattr__(self, "_size", start + int(meta.obs_shape[0]))
        # the true part: the readings, the targets, then the tool and the task's points
        tool = spec.n_joints + int(task.uses_gripper) + spec.n_actuators
        object.__setattr__(self, "_tool", tool)

    @property
    def n_inputs(self) -> int:
        return 6

    def check_env(self, env_kwargs: Mapping[str, Any]) -> None:
        """Refuse an env (its construction kwargs, ``env.spec.kwargs``) that acts unlike the one
        the policy was trained in (``ACTING_KWARGS``)."""
        meta, defaults = self._policy.meta, _env_defaults()
        trained = {
            **{k: meta.env_kwargs.get(k, defaults.get(k)) for k in ACTING_KWARGS},
            "task": meta.task,
            "control_hz": meta.control_hz,
            "max_delta_rad": meta.max_delta_rad,
        }
        for key in ACTING_KWARGS:
            have = env_kwargs.get(key, defaults.get(key))
            if have != trained[key]:
                raise ConfigError(
                    f"teacher policy {self.policy_name!r} was trained with {key}={trained[key]!r}; "
                    f"the env has {key}={have!r}: set env_kwargs.{key}={trained[key]!r}"
                )

    def _state_obs(self, privileged: np.ndarray) -> np.ndarray:
        p = np.asarray(privileged, dtype=np.float32).reshape(-1)
        if p.size != self._size:
            raise ConfigError(
                f"teacher policy {self.policy_name!r} needs a privileged state of {self._size} "
                f"values ({self._start} true, then its {self._size - self._start}-value state "
                f"observation); got {p.size}: an env of another task or layout"
            )
        return p[self._start :]

    def action(self, privileged: np.ndarray) -> np.ndarray:
        """(action_dim,) float32 in [-1, 1]."""
        out = self._policy(self._state_obs(privileged))
        return np.clip(out, -1.0, 1.0).astype(np.float32)

    def inputs(self, privileged: np.ndarray) -> np.ndarray:
        p = np.asarray(privileged, dtype=np.float32).reshape(-1)
        return p[self._tool : self._tool + 6] * np.float32(10.0)
