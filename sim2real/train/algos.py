"""One registry of the stable-baselines3 algorithms, with the diagnostics ``compare`` plots.

SB3 already logs most of what an engineer looks at when a run goes wrong (PPO's clip fraction and
approx-KL, the actor and critic losses). The few it does not log — A2C's gradient norm, the
Q-values of DQN, DDPG, TD3 and SAC, the actor's action statistics — are added here by thin
subclasses that call the SB3 update unchanged and record afterwards. The extra replay-buffer sample
restores numpy's global RNG, so an instrumented run takes the same steps as a plain one.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th
from stable_baselines3 import A2C, DDPG, DQN, PPO, SAC, TD3
from stable_baselines3.common.buffers import NStepReplayBuffer

from sim2real.errors import ConfigError, UnknownNameError
from sim2real.train.distill import Distill

DIAG_EVERY = 20  # train() calls between diagnostic samples (one extra forward pass each)


def _sample_without_rng_side_effects(model: Any, batch_size: int) -> Any:
    state = np.random.get_state()
    try:
        return model.replay_buffer.sample(batch_size, env=model._vec_normalize_env)
    finally:
        np.random.set_state(state)


class _ActorCriticDiagnostics:
    """Q-value and action statistics for DDPG/TD3/SAC, computed on a replay batch."""

    _diag_calls = 0

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        super().train(gradient_steps, batch_size)  # type: ignore[misc]
        self._diag_calls += 1
        if self._diag_calls % DIAG_EVERY == 1:
            self._record_diagnostics(batch_size)

    def _policy_actions(self, obs: Any) -> th.Tensor:
        return self.actor(obs)  # type: ignore[attr-defined]

    def _record_diagnostics(self, batch_size: int) -> None:
        data = _sample_without_rng_side_effects(self, batch_size)
        with th.no_grad():
            actions = self._policy_actions(data.observations)
            q = self.critic(data.observations, actions)[0]  # type: ignore[attr-defined]
        log = self.logger  # type: ignore[attr-defined]
        log.record("train/q_mean", float(q.mean()))
        log.record("train/action_mean", float(actions.mean()))
        log.record("train/action_std", float(actions.std()))


class DDPGDiag(_ActorCriticDiagnostics, DDPG):
    pass


class TD3Diag(_ActorCriticDiagnostics, TD3):
    pass


class SACDiag(_ActorCriticDiagnostics, SAC):
    def _policy_actions(self, obs: Any) -> th.Tensor:
        actions, _ = self.actor.action_log_prob(obs)
        return actions


class DQNDiag(DQN):
    """Adds the mean and max of the greedy Q-value on a replay batch, and double Q-learning.

    ``double_q`` (van Hasselt et al. 2016): the online network picks the next action, the target
    network values it, which removes the max operator's upward bias. SB3's DQN lacks it and so
    does sb3-contrib (it has QR-DQN); n-step returns need nothing here, SB3's ``n_steps``
    argument (``NStepReplayBuffer``) provides them. The double target is taken by handing SB3's
    unchanged update a target network whose output is the online-selected action's value."""

    _diag_calls = 0

    def __init__(self, *args: Any, double_q: bool = False, **kwargs: Any) -> None:
        if not isinstance(double_q, bool):
            raise ConfigError(f"dqn double_q must be true or false, got {double_q!r}")
        self.double_q = double_q
        super().__init__(*args, **kwargs)

    def _setup_model(self) -> None:
        # A saved n-step model carries NStepReplayBuffer with its n_steps in replay_buffer_kwargs;
        # SB3 then warns, wrongly, on every load that n_steps is ignored.
        kw = self.replay_buffer_kwargs or {}
        saved_n_step = (
            self.replay_buffer_class is NStepReplayBuffer and kw.get("n_steps") == self.n_steps
        )
        with warnings.catch_warnings():
            if saved_n_step:
                warnings.filterwarnings("ignore", message=r"`n_steps=\d+` is ignored")
            super()._setup_model()

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        if self.double_q:
            target = self.q_net_target
            self.q_net_target = _DoubleQTarget(self.q_net, target)  # type: ignore[assignment]
            try:
                super().train(gradient_steps, batch_size)
            finally:
                self.q_net_target = target
        else:
            super().train(gradient_steps, batch_size)
        self._diag_calls += 1
        if self._diag_calls % DIAG_EVERY == 1:
            data = _sample_without_rng_side_effects(self, batch_size)
            with th.no_grad():
                q = self.q_net(data.observations).max(dim=1).values
            self.logger.record("train/q_mean", float(q.mean()))
            self.logger.record("train/q_max", float(q.max()))


class _DoubleQTarget(th.nn.Module):
    """Stands in for the target network inside one ``DQN.train`` call: SB3 takes the max over
    actions of what it returns, so every action is given the target's value of the action the
    online network prefers; the max is then exactly the double-Q estimate."""

    def __init__(self, online: th.nn.Module, target: th.nn.Module) -> None:
        super().__init__()
        self.online = online
        self.target = target

    def forward(self, obs: Any) -> th.Tensor:
        q_target = self.target(obs)
        best = self.online(obs).argmax(dim=1, keepdim=True)
        return th.gather(q_target, 1, best).expand_as(q_target)


class A2CDiag(A2C):
    """Adds the gradient norm *before* clipping (SB3 clips it and throws the norm away)."""

    _grad_sq = 0.0

    def _setup_model(self) -> None:
        super()._setup_model()
        for p in self.policy.parameters():
            p.register_post_accumulate_grad_hook(self._accumulate_grad)

    def _accumulate_grad(self, p: th.Tensor) -> None:
        if p.grad is not None:
            self._grad_sq += float(p.grad.detach().pow(2).sum())

    def train(self) -> None:
        self._grad_sq = 0.0
        super().train()
        self.logger.record("train/grad_norm", math.sqrt(self._grad_sq))


@dataclass(frozen=True)
class AlgoSpec:
    """How the trainer treats one algorithm."""

    name: str
    cls: Callable[..., Any]
    off_policy: bool
    discrete_actions: bool  # acts in Discrete(N) only: Box envs get the joint-delta table
    action_noise: bool
    diagnostics: tuple[str, ...]
    doc: str
    accepts_discrete: bool = False  # trains on an env whose own action space is Discrete
    privileged_critic: bool = False  # has a separate critic that may see the privileged state
    needs_privileged: bool = False  # always trains on the privileged state (a teacher reads it)


_AC_DIAG = ("train/actor_loss", "train/critic_loss", "train/q_mean", "train/action_mean")
ALGOS: dict[str, AlgoSpec] = {
    "ddpg": AlgoSpec(
        "ddpg", DDPGDiag, True, False, True, (*_AC_DIAG, "train/action_std"), "off-policy, det."
    ),
    "td3": AlgoSpec(
        "td3", TD3Diag, True, False, True, (*_AC_DIAG, "train/action_std"), "twin critics, delay"
    ),
    "sac": AlgoSpec(
        "sac",
        SACDiag,
        True,
        False,
        False,
        (*_AC_DIAG, "train/action_std", "train/ent_coef"),
        "max-entropy off-policy",
    ),
    "ppo": AlgoSpec(
        "ppo",
        PPO,
        False,
        False,
        False,
        ("train/clip_fraction", "train/entropy_loss", "train/value_loss", "train/approx_kl"),
        "clipped on-policy",
        accepts_discrete=True,
        privileged_critic=True,
    ),
    "a2c": AlgoSpec(
        "a2c",
        A2CDiag,
        False,
        False,
        False,
        ("train/value_loss", "train/entropy_loss", "train/grad_norm"),
        "synchronous actor-critic",
        accepts_discrete=True,
        privileged_critic=True,
    ),
    "dqn": AlgoSpec(
        "dqn",
        DQNDiag,
        True,
        True,
        False,
        ("rollout/exploration_rate", "train/q_mean", "train/loss"),
        "discrete joint deltas",
        accepts_discrete=True,
    ),
    "distill": AlgoSpec(
        "distill",
        Distill,
        False,
        False,  # acts in the env's own space, as its teacher does (Discrete Kuka, Box arm)
        False,
        ("train/distill_loss", "train/teacher_agreement", "train/batch_accuracy"),
        "DAgger from a privileged teacher",
        accepts_discrete=True,
        needs_privileged=True,
    ),
}


def get_algo(name: str) -> AlgoSpec:
    try:
        return ALGOS[name.lower()]
    except KeyError:
        raise UnknownNameError("algo", name, ALGOS) from None


ACTIVATIONS: dict[str, type[th.nn.Module]] = {
    "relu": th.nn.ReLU,
    "tanh": th.nn.Tanh,
    "elu": th.nn.ELU,
    "leaky_relu": th.nn.LeakyReLU,
}
