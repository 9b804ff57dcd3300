"""Teacher → student distillation by DAgger (Ross et al. 2011), as an SB3 algorithm.

The teacher is privileged: a pure function of the simulator's state (``TEACHERS``; the Kuka
scripted servo reaches ~70% held-out grasp success). The student is the pixel actor of an
``AsymmetricActorCriticPolicy`` (its critic is unused), so a distilled run saves, loads,
evaluates and compares exactly like a PPO run. Each iteration:

1. the student acts in ``n_envs`` training envs for ``n_steps`` (SB3's on-policy rollout loop:
   callbacks, episode logs, checkpoints and the wall-clock limit work unchanged);
2. the teacher labels every visited state from its privileged state (β = 0: the student's own
   state distribution from the first iteration; the start distribution is the same for both);
3. the labelled frames join an aggregated dataset (the newest ``dataset_size`` frames);
4. ``gradient_steps`` minibatches from that dataset minimise the student's cross-entropy to the
   teacher's action.

The aggregated dataset is not saved with a checkpoint: a resumed run starts a new one.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

from sim2real.errors import ConfigError, UnknownNameError
from sim2real.train.asymmetric import AsymmetricActorCriticPolicy
from sim2real.train.augment import PRIVILEGED_KEY


def _kuka_scripted(privileged: np.ndarray) -> int:
    from sim2real.envs.kuka_grasp import privileged_teacher_action

    return privileged_teacher_action(privileged)


# Teacher name → privileged state vector → action. Module-level functions, so a model pickles.
TEACHERS: dict[str, Callable[[np.ndarray], Any]] = {"kuka_scripted": _kuka_scripted}


def get_teacher(name: str) -> Callable[[np.ndarray], Any]:
    try:
        return TEACHERS[name]
    except KeyError:
        raise UnknownNameError("teacher", name, TEACHERS) from None


class Distill(OnPolicyAlgorithm):
    """DAgger from a privileged teacher into a pixel student (see the module docstring)."""

    policy_aliases = {  # noqa: RUF012  (SB3's class attribute)
        "MultiInputPolicy": AsymmetricActorCriticPolicy,
        "AsymmetricPolicy": AsymmetricActorCriticPolicy,
    }

    def __init__(
        self,
        policy: str | type[AsymmetricActorCriticPolicy],
        env: Any,
        teacher: str = "kuka_scripted",
        learning_rate: float | Callable[[float], float] = 3e-4,
        n_steps: int = 256,
        batch_size: int = 256,
        gradient_steps: int = 16,
        dataset_size: int = 50_000,
        ent_coef: float = 0.0,
        max_grad_norm: float = 0.5,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        get_teacher(teacher)  # unknown names fail before anything is built
        for name, value in (
            ("n_steps", n_steps),
            ("batch_size", batch_size),
            ("gradient_steps", gradient_steps),
            ("dataset_size", dataset_size),
        ):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"distill {name} must be an integer >= 1, got {value!r}")
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            n_steps=n_steps,
            gamma=0.99,
            gae_lambda=1.0,
            ent_coef=ent_coef,
            vf_coef=0.0,
            max_grad_norm=max_grad_norm,
            use_sde=False,
            sde_sample_freq=-1,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
            supported_action_spaces=(spaces.Discrete,),
        )
        self.teacher = teacher
        self.batch_size = batch_size
        self.gradient_steps = gradient_steps
        self.dataset_size = dataset_size
        self._data: dict[str, np.ndarray] = {}
        self._labels = np.zeros(0, dtype=np.int64)
        self._data_pos = 0
        self._data_len = 0
        if _init_setup_model:
            self._setup_model()

    @staticmethod
    def check_hyperparams(hp: dict[str, Any]) -> None:
        """What the trainer's config check asks before a run dir is written."""
        get_teacher(str(hp.get("teacher", "kuka_scripted")))

    def _setup_model(self) -> None:
        if (
            not isinstance(self.observation_space, spaces.Dict)
            or PRIVILEGED_KEY not in self.observation_space.spaces
        ):
            raise ConfigError(
                f"distill needs the env's privileged state ({PRIVILEGED_KEY!r} observation key); "
                f"got {self.observation_space}"
            )
        super()._setup_model()
        self._data = {}  # allocated at the first rollout: loading for inference needs none
        self._data_pos = self._data_len = 0

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_data", "_labels"]

    def _aggregate(self) -> float:
        """Teacher labels for this rollout's states, into the dataset; returns how often the
        student's executed action already agreed with the teacher."""
        buf = self.rollout_buffer
        obs = buf.observations
        assert isinstance(obs, dict)
        teacher = get_teacher(self.teacher)
        priv = obs[PRIVILEGED_KEY].reshape(-1, obs[PRIVILEGED_KEY].shape[-1])
        labels = np.array([int(teacher(p)) for p in priv], dtype=np.int64)
        executed = buf.actions.reshape(-1).astype(np.int64)
        n = len(labels)
        if not self._data:
            assert isinstance(self.observation_space, spaces.Dict)
            for k, space in self.observation_space.spaces.items():
                if k != PRIVILEGED_KEY:
                    shape = (self.dataset_size, *(space.shape or ()))
                    self._data[k] = np.zeros(shape, dtype=space.dtype)
            self._labels = np.zeros(self.dataset_size, dtype=np.int64)
        idx = (self._data_pos + np.arange(n)) % self.dataset_size
        for k, store in self._data.items():
            flat = obs[k].reshape(n, *store.shape[1:])
            store[idx] = flat.astype(store.dtype)  # the rollout buffer keeps frames as float32
        self._labels[idx] = labels
        self._data_pos = int((self._data_pos + n) % self.dataset_size)
        self._data_len = min(self._data_len + n, self.dataset_size)
        return float(np.mean(executed == labels))

    def train(self) -> None:
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        agreement = self._aggregate()
        losses, entropies, accs = [], [], []
        for _ in range(self.gradient_steps):
            idx = np.random.randint(0, self._data_len, size=min(self.batch_size, self._data_len))
            obs = {k: th.as_tensor(v[idx], device=self.device) for k, v in self._data.items()}
            target = th.as_tensor(self._labels[idx], device=self.device)
            dist = self.policy.get_distribution(obs)
            ent = dist.entropy()
            assert ent is not None  # a categorical distribution has one
            entropy = ent.mean()
            loss = -dist.log_prob(target).mean() - self.ent_coef * entropy
            self.policy.optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()
            with th.no_grad():
                greedy = dist.get_actions(deterministic=True)
                accs.append(float((greedy == target).float().mean()))
            losses.append(loss.item())
            entropies.append(entropy.item())
        self._n_updates += self.gradient_steps
        log = self.logger
        log.record("train/distill_loss", float(np.mean(losses)))
        log.record("train/teacher_agreement", agreement)
        log.record("train/batch_accuracy", float(np.mean(accs)))
        log.record("train/entropy", float(np.mean(entropies)))
        log.record("train/dataset_size", self._data_len)
        log.record("train/n_updates", self._n_updates, exclude="tensorboard")
