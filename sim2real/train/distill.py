"""Teacher → student distillation by DAgger (Ross et al. 2011), as an SB3 algorithm.

The teacher is privileged: a pure function of the simulator's state (``TEACHERS``; the Kuka
scripted servo reaches ~70% held-out grasp success, the arm's reach servo 100 % within 2 cm, and
a shipped state policy, ``pick_ppo``, acts on the state observation at the privileged state's
tail, ``state_teacher``; the scripted ``pick_servo`` picks 100 %), built for the env's own action decoding (its arm spec and step size). The student is the pixel
actor of an ``AsymmetricActorCriticPolicy`` (its critic is unused), so a distilled run saves,
loads, evaluates and compares exactly like a PPO run. Each iteration:

1. the student acts in ``n_envs`` training envs for ``n_steps`` (SB3's on-policy rollout loop:
   callbacks, episode logs, checkpoints and the wall-clock limit work unchanged);
2. the teacher labels every visited state from its privileged state (β = 0: the student's own
   state distribution from the first iteration; the start distribution is the same for both);
3. the labelled frames join an aggregated dataset (the newest ``dataset_size`` frames);
4. ``gradient_steps`` minibatches from that dataset minimise the student's cross-entropy to the
   teacher's action (``Discrete``) or the squared error of its Gaussian's mean to the teacher's
   action (``Box``, see ``Distill``), plus ``aux_coef`` times the squared error of an auxiliary
   head that regresses the teacher's *inputs* (for Kuka: the nearest object's offset from the
   gripper target; for reach: the target and the tool) from the student's image features. One
   frame rarely pins down which of two good moves the teacher picked, but always where the
   object is; the auxiliary target says so directly. The head is training-only: it is not part
   of the exported actor.

The aggregated dataset is not saved with a checkpoint: a resumed run starts a new one.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

from sim2real.errors import ConfigError, UnknownNameError
from sim2real.train.asymmetric import AsymmetricActorCriticPolicy
from sim2real.train.augment import PRIVILEGED_KEY

if TYPE_CHECKING:
    from sim2real.observation import ActionDecoder

# A continuous student "agrees" with its teacher when every joint's action is within this of the
# teacher's (normalised units: 0.01 rad at the default 0.1 rad step, ~2 mm of tool at 20 cm).
AGREEMENT_TOL = 0.1
# ``reach_servo``'s step: 0.5 already winds up through ``shifted``'s two steps of servo latency
# (54 % within 2 cm), 0.4 does not (``bench/reach_teacher.py``).
REACH_SERVO_GAIN = 0.4


def _kuka_scripted(privileged: np.ndarray) -> int:
    from sim2real.envs.kuka_grasp import privileged_teacher_action

    return privileged_teacher_action(privileged)


def _kuka_inputs(privileged: np.ndarray) -> np.ndarray:
    """What the Kuka servo decides on, in 0.1 m units: the nearest object's offset from the
    target (0 when none is live), the target's x, y and the episode's progress."""
    from sim2real.envs.kuka_grasp import nearest_object_offset

    p = np.asarray(privileged, dtype=np.float32).reshape(-1)
    offset = nearest_object_offset(p)
    near = np.zeros(2, np.float32) if offset is None else offset.astype(np.float32)
    return np.concatenate((near, p[:2], p[4:5]))


@dataclass(frozen=True)
class Teacher:
    """A privileged teacher: its action, and the inputs it decides on (the auxiliary target)."""

    action: Callable[[np.ndarray], Any]
    inputs: Callable[[np.ndarray], np.ndarray]
    n_inputs: int
    continuous: bool = False  # a Box action in the env's normalised units, else a Discrete index
    # Refuses an env (its construction kwargs) it would mislabel; None: any env of its kind.
    check_env: Callable[[Mapping[str, Any]], None] | None = None


KUKA_SCRIPTED = Teacher(_kuka_scripted, _kuka_inputs, 5)


def _kuka_teacher(decoder: ActionDecoder | None) -> Teacher:
    return KUKA_SCRIPTED


@functools.cache
def _nominal_decoder() -> ActionDecoder:
    """The shipped arm at the envs' default step: a teacher asked for without an env."""
    from hardware.spec import load_spec
    from sim2real.observation import ActionDecoder

    return ActionDecoder(load_spec())


def _reach(decoder: ActionDecoder | None, gain: float, steer: str) -> Teacher:
    from sim2real.envs.reach import ReachServo

    servo = ReachServo(decoder or _nominal_decoder(), gain, steer)
    return Teacher(servo.action, servo.inputs, servo.n_inputs, continuous=True)


def _reach_ik(decoder: ActionDecoder | None) -> Teacher:
    """The command set to the IK solution: the most exact reach teacher."""
    return _reach(decoder, 1.0, "command")


def _reach_servo(decoder: ActionDecoder | None) -> Teacher:
    """A visual servo on the true joints: the reach teacher a camera policy imitates best."""
    return _reach(decoder, REACH_SERVO_GAIN, "joints")


def _state_policy(policy_name: str, decoder: ActionDecoder | None) -> Teacher:
    """A shipped state policy on the state observation the pixel env reports privileged."""
    from sim2real.train.state_teacher import StatePolicyTeacher

    t = StatePolicyTeacher(policy_name, decoder)
    return Teacher(t.action, t.inputs, t.n_inputs, continuous=True, check_env=t.check_env)


def _pick_servo(decoder: ActionDecoder | None) -> Teacher:
    """The scripted pick on the truth: over the cube, down, close, lift (``pick.PickServo``)."""
    from sim2real.envs.pick import PickServo
    from sim2real.observation import ActionDecoder

    if decoder is None:
        from hardware.spec import load_spec

        decoder = ActionDecoder(load_spec(), use_gripper=True)
    servo = PickServo(decoder)
    return Teacher(servo.action, servo.inputs, servo.n_inputs, continuous=True)


# Teacher name → the teacher built for an env's action decoder (its arm spec and step size; None:
# an env without one, or no env: the shipped arm). A model saves the name, never the teacher.
TEACHERS: dict[str, Callable[[ActionDecoder | None], Teacher]] = {
    "kuka_scripted": _kuka_teacher,
    "reach_ik": _reach_ik,
    "reach_servo": _reach_servo,
    "pick_servo": _pick_servo,
    # shipped state pick policies (``sim2real policies``), on the state observation
    "pick_ppo": functools.partial(_state_policy, "pick-ppo"),
    "pick_ddpg": functools.partial(_state_policy, "pick-ddpg"),
}


def get_teacher(name: str, decoder: ActionDecoder | None = None) -> Teacher:
    try:
        build = TEACHERS[name]
    except KeyError:
        raise UnknownNameError("teacher", name, TEACHERS) from None
    return build(decoder)


class Distill(OnPolicyAlgorithm):
    """DAgger from a privileged teacher into a pixel student (see the module docstring).

    A ``Box`` student is trained by the squared error of its Gaussian's *mean* to the teacher's
    action, not by its negative log-likelihood: the NLL weighs the mean's error by 1/σ², so as σ
    shrinks the effective step size grows and the fit of the precise, small corrections near the
    goal (what success is judged on) turns noisy, while the mean is all that the deterministic,
    evaluated policy uses. σ is therefore not learned: it stays at ``policy_kwargs.log_std_init``,
    the DAgger rollouts' exploration around the student's own path (``ent_coef`` must be 0).
    """

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
        aux_coef: float = 0.0,
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
        spec = get_teacher(teacher)  # unknown names fail before anything is built
        if spec.continuous and ent_coef:
            raise ConfigError(
                f"distill ent_coef must be 0 for the continuous teacher {teacher!r} (the student's "
                f"std is fixed at policy_kwargs.log_std_init), got {ent_coef!r}"
            )
        if isinstance(aux_coef, bool) or not isinstance(aux_coef, int | float) or aux_coef < 0:
            raise ConfigError(f"distill aux_coef must be a number >= 0, got {aux_coef!r}")
        want = spaces.Box if spec.continuous else spaces.Discrete
        space = getattr(env, "action_space", None)
        # SB3's ``load`` builds with the default teacher, then sets the saved one: check new models
        if _init_setup_model and space is not None and not isinstance(space, want):
            raise ConfigError(
                f"distill teacher {teacher!r} acts in a {want.__name__} space; the env's actions "
                f"are {space}"
            )
        if aux_coef:
            policy_kwargs = {**(policy_kwargs or {}), "aux_dim": spec.n_inputs}
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
            supported_action_spaces=(spaces.Discrete, spaces.Box),
        )
        self.teacher = teacher
        self.batch_size = batch_size
        self.gradient_steps = gradient_steps
        self.dataset_size = dataset_size
        self.aux_coef = float(aux_coef)
        self._data: dict[str, np.ndarray] = {}
        self._labels = np.zeros(0, dtype=np.float32 if spec.continuous else np.int64)
        self._aux = np.zeros((0, spec.n_inputs), dtype=np.float32)
        self._data_pos = 0
        self._data_len = 0
        self._bound: Teacher | None = None
        self._action_error = 0.0
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
        self._bound = None
        if self.env is not None:
            self._teacher()  # a teacher that would mislabel this env fails before training

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_data", "_labels", "_aux", "_bound"]

    @property
    def continuous(self) -> bool:
        return isinstance(self.action_space, spaces.Box)

    def _teacher(self) -> Teacher:
        """The teacher built for the training env's action decoding (once; not saved)."""
        bound = getattr(self, "_bound", None)  # a loaded model has none
        if bound is None:
            env = self.env
            decoder = None
            if env is not None and env.has_attr("decoder"):
                decoder = env.get_attr("decoder", [0])[0]
            bound = get_teacher(self.teacher, decoder)
            spec = env.get_attr("spec", [0])[0] if env is not None else None
            if bound.check_env is not None and spec is not None:
                bound.check_env(spec.kwargs)
            self._bound = bound
        return bound

    def _labelled(self, priv: np.ndarray, teacher: Teacher) -> np.ndarray:
        if self.continuous:
            return np.stack([teacher.action(p) for p in priv]).astype(np.float32)
        return np.array([int(teacher.action(p)) for p in priv], dtype=np.int64)

    def _agreement(self, actions: np.ndarray, labels: np.ndarray) -> np.ndarray:
        """Per frame: the student's action is the teacher's (continuous: within
        ``AGREEMENT_TOL`` on every dimension, after the env's clip to the action space)."""
        if not self.continuous:
            return actions.reshape(-1).astype(np.int64) == labels
        return np.all(np.abs(self._clip(actions) - labels) <= AGREEMENT_TOL, axis=-1)

    def _clip(self, actions: np.ndarray) -> np.ndarray:
        """What the env executes of a ``Box`` action (SB3 clips it to the space)."""
        assert isinstance(self.action_space, spaces.Box)
        return np.clip(actions, self.action_space.low, self.action_space.high)

    def _aggregate(self) -> float:
        """Teacher labels for this rollout's states, into the dataset; returns how often the
        student's executed action already agreed with the teacher."""
        buf = self.rollout_buffer
        obs = buf.observations
        assert isinstance(obs, dict)
        teacher = self._teacher()
        priv = obs[PRIVILEGED_KEY].reshape(-1, obs[PRIVILEGED_KEY].shape[-1])
        labels = self._labelled(priv, teacher)
        n = len(labels)
        executed = buf.actions.reshape(n, -1)
        if not self._data:
            assert isinstance(self.observation_space, spaces.Dict)
            for k, space in self.observation_space.spaces.items():
                if k != PRIVILEGED_KEY:
                    shape = (self.dataset_size, *(space.shape or ()))
                    self._data[k] = np.zeros(shape, dtype=space.dtype)
            self._labels = np.zeros((self.dataset_size, *labels.shape[1:]), dtype=labels.dtype)
            if self.aux_coef:
                self._aux = np.zeros((self.dataset_size, teacher.n_inputs), dtype=np.float32)
        idx = (self._data_pos + np.arange(n)) % self.dataset_size
        for k, store in self._data.items():
            flat = obs[k].reshape(n, *store.shape[1:])
            store[idx] = flat.astype(store.dtype)  # the rollout buffer keeps frames as float32
        self._labels[idx] = labels
        if self.aux_coef:
            self._aux[idx] = np.stack([teacher.inputs(p) for p in priv])
        self._data_pos = int((self._data_pos + n) % self.dataset_size)
        self._data_len = min(self._data_len + n, self.dataset_size)
        if self.continuous:
            self._action_error = float(np.mean(np.abs(self._clip(executed) - labels)))
        return float(np.mean(self._agreement(executed, labels)))

    def train(self) -> None:
        """Aggregate this rollout's labels, then ``gradient_steps`` minibatches of the imitation
        loss (``_imitation_loss``) plus the auxiliary head's."""
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        agreement = self._aggregate()
        losses, aux_losses = [], []
        stats: dict[str, list[float]] = {}
        policy = self.policy
        assert isinstance(policy, AsymmetricActorCriticPolicy)
        for _ in range(self.gradient_steps):
            idx = np.random.randint(0, self._data_len, size=min(self.batch_size, self._data_len))
            obs = {k: th.as_tensor(v[idx], device=self.device) for k, v in self._data.items()}
            features = policy.actor_features(obs)
            loss, batch = self._imitation_loss(policy, features, idx)
            if self.aux_coef and policy.aux_head is not None:
                aux_target = th.as_tensor(self._aux[idx], device=self.device)
                aux_loss = th.nn.functional.mse_loss(policy.aux_head(features), aux_target)
                loss = loss + self.aux_coef * aux_loss
                aux_losses.append(aux_loss.item())
            self.policy.optimizer.zero_grad()
            loss.backward()
            th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()
            losses.append(loss.item())
            for key, value in batch.items():
                stats.setdefault(key, []).append(value)
        self._n_updates += self.gradient_steps
        log = self.logger
        log.record("train/distill_loss", float(np.mean(losses)))
        log.record("train/teacher_agreement", agreement)
        if self.continuous:
            log.record("train/action_error", self._action_error)
            log.record("train/std", th.exp(policy.log_std.detach()).mean().item())
        for key, values in stats.items():
            log.record(f"train/{key}", float(np.mean(values)))
        if aux_losses:
            log.record("train/aux_loss", float(np.mean(aux_losses)))
        log.record("train/dataset_size", self._data_len)
        log.record("train/n_updates", self._n_updates, exclude="tensorboard")

    def _imitation_loss(
        self, policy: AsymmetricActorCriticPolicy, features: th.Tensor, idx: np.ndarray
    ) -> tuple[th.Tensor, dict[str, float]]:
        """The student's loss against the teacher's labels ``idx`` and its batch statistics:
        cross-entropy (less the entropy bonus) for ``Discrete``; for ``Box`` the squared error of
        the Gaussian's mean (see the class docstring)."""
        target = th.as_tensor(self._labels[idx], device=self.device)
        latent = policy.mlp_extractor.forward_actor(features)
        if self.continuous:
            mean = policy.action_net(latent)
            with th.no_grad():
                greedy, labels = mean.detach().cpu().numpy(), self._labels[idx]
                batch = {
                    "batch_accuracy": float(np.mean(self._agreement(greedy, labels))),
                    "batch_action_error": float(np.mean(np.abs(self._clip(greedy) - labels))),
                }
            return th.nn.functional.mse_loss(mean, target), batch
        # get_distribution's own path, with the features kept for the auxiliary head.
        dist = policy._get_action_dist_from_latent(latent)
        ent = dist.entropy()
        assert ent is not None  # a categorical distribution has one
        entropy = ent.mean()
        with th.no_grad():
            greedy_t = dist.get_actions(deterministic=True)
            batch = {
                "batch_accuracy": float((greedy_t == target).float().mean()),
                "entropy": entropy.item(),
            }
        return -dist.log_prob(target).mean() - self.ent_coef * entropy, batch
