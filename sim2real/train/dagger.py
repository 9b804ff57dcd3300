"""Teacher → student DAgger for a *state* policy of any SB3 algorithm: a stage before ``learn``.

Why: pick on what the cameras see (the cube estimate held at its last sighting while the fingers
hide it, delays, noise) is a hard exploration problem for RL from scratch. PPO reached 36.5 %
after 5.2 M steps (the shipped ``pick-ppo`` before this stage), while a scripted pick on the
simulator's truth (``pick.PickServo``) picks every cube. DAgger (Ross et al. 2011) turns that
teacher into a student that acts on the realistic observation alone, in minutes:

1. the envs run ``iterations`` rounds of ``steps_per_iteration`` steps each. In the first
   ``teacher_iterations`` the teacher acts (β = 1), after that the student does (β = 0), with
   Gaussian exploration noise; every visited state is labelled by the teacher from the env's
   ``privileged_state`` (read through ``VecEnv.env_method``, never part of the observation);
2. after each round the student's action (the Gaussian's mean for PPO and A2C, the
   deterministic actor for DDPG and TD3) regresses to the labels of every state so far, on the
   observation as the run's ``VecNormalize`` normalises it;
3. the critic learns the student's returns with the actor fixed, so the algorithm's first
   updates climb a critic that knows the policy, not a random one: off-policy algorithms
   (``critic_updates``, ``warmstart``'s updates on every transition, which also fill the replay
   buffer), on-policy ones (``value_epochs`` of the value head on the student's discounted
   returns).

Then SB3 learns, with an **anchor** (``ImitationAnchor``) where the preset asks for one: the
teacher goes on labelling the states the learner visits, and after each of the algorithm's
updates a few minibatches of imitation pull the actor back. Alone, the algorithms undid the
imitation on pick (PPO 95.5 % → 83.5 % in 500k steps, DDPG to 0 % in 10k); with the anchor they
refine it (PPO 99.0 %, DDPG 98.5 %; ``docs/studies/pick.md``). The transitions count against
the run's step budget and its wall-clock limit. The student is an ordinary model of its
algorithm: it saves, exports, evaluates and deploys as any other run.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from torch.nn import functional

from sim2real.errors import ConfigError, UnknownNameError


@dataclass(frozen=True)
class Dagger:
    """The preset's ``dagger`` mapping, validated."""

    teacher: str  # a privileged teacher of ``distill.TEACHERS`` with continuous actions
    iterations: int = 40
    steps_per_iteration: int = 250  # env steps per env per round
    teacher_iterations: int = 1  # the first rounds act with the teacher (β = 1)
    updates_per_iteration: int = 1500  # minibatches after each round
    batch_size: int = 256
    learning_rate: float = 1e-3
    noise_sigma: float = 0.1  # exploration around the student's action, normalised units
    critic_updates: int = 0  # off-policy: Q updates with the actor fixed
    value_epochs: int = 0  # on-policy: epochs of value regression on the student's returns
    # While the algorithm then learns: every ``anchor_every`` env steps (all envs together),
    # ``anchor_updates`` minibatches of the imitation loss, the teacher labelling the states the
    # learner visits (DAgger goes on beside the RL updates, as in kickstarting, Schmitt et al.
    # 2018). 0: the algorithm learns alone (measured on pick: PPO then lost 9.5 points in 500k
    # steps, DDPG its whole grasp within 10k).
    anchor_every: int = 0
    anchor_updates: int = 0
    dataset_size: int = 200_000  # labelled states kept (the newest), all envs together

    def __post_init__(self) -> None:
        if not isinstance(self.teacher, str) or not self.teacher:
            raise ConfigError(f"dagger.teacher must name a teacher, got {self.teacher!r}")
        for name in (
            "iterations",
            "steps_per_iteration",
            "updates_per_iteration",
            "batch_size",
            "dataset_size",
        ):
            _check_int(name, getattr(self, name), 1)
        for name in (
            "teacher_iterations",
            "critic_updates",
            "value_epochs",
            "anchor_every",
            "anchor_updates",
        ):
            _check_int(name, getattr(self, name), 0)
        if self.teacher_iterations > self.iterations:
            raise ConfigError(
                f"dagger.teacher_iterations ({self.teacher_iterations}) must be <= iterations "
                f"({self.iterations})"
            )
        if bool(self.anchor_every) != bool(self.anchor_updates):
            raise ConfigError(
                f"dagger.anchor_every ({self.anchor_every}) and anchor_updates "
                f"({self.anchor_updates}) are both 0 (no anchor) or both >= 1"
            )
        lr, s = self.learning_rate, self.noise_sigma
        if isinstance(lr, bool) or not isinstance(lr, int | float) or not 0 < lr < 1:
            raise ConfigError(f"dagger.learning_rate must be in (0, 1), got {lr!r}")
        if isinstance(s, bool) or not isinstance(s, int | float) or not 0 <= s <= 1:
            raise ConfigError(f"dagger.noise_sigma must be in [0, 1], got {s!r}")

    @classmethod
    def from_mapping(cls, data: Any) -> Dagger:
        if not isinstance(data, Mapping):
            raise ConfigError(
                f"dagger must be a mapping like {{teacher: pick_servo}}, got {data!r}"
            )
        known = [f.name for f in fields(cls)]
        unknown = sorted(set(data) - set(known))
        if unknown:
            raise ConfigError(f"dagger: unknown key(s) {unknown}; valid: {sorted(known)}")
        if "teacher" not in data:
            raise ConfigError("dagger needs a teacher (one of distill's teachers)")
        from sim2real.train.distill import TEACHERS

        if data["teacher"] not in TEACHERS:
            raise UnknownNameError("dagger teacher", str(data["teacher"]), TEACHERS)
        return cls(**dict(data))


def _check_int(name: str, value: Any, low: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ConfigError(f"dagger.{name} must be an integer >= {low}, got {value!r}")


# ---- the student's action, per algorithm -------------------------------------------------------
@dataclass(frozen=True)
class StudentActor:
    """What DAgger trains of a model: its deterministic action on normalised observations, the
    parameters that make it, and what to do once they changed (an off-policy target copy)."""

    act: Callable[[th.Tensor], th.Tensor]
    parameters: Callable[[], Iterator[th.nn.Parameter]]
    after_fit: Callable[[], None]


def _gaussian_mean(model: Any) -> StudentActor:
    """PPO / A2C: the mean of the policy's Gaussian (what ``predict(deterministic=True)`` is)."""
    policy = model.policy

    def act(obs: th.Tensor) -> th.Tensor:
        features = policy.extract_features(obs, policy.pi_features_extractor)
        return policy.action_net(policy.mlp_extractor.forward_actor(features))

    def parameters() -> Iterator[th.nn.Parameter]:
        yield from policy.pi_features_extractor.parameters()
        yield from policy.mlp_extractor.policy_net.parameters()
        yield from policy.action_net.parameters()

    return StudentActor(act, parameters, lambda: None)


def _deterministic_actor(model: Any) -> StudentActor:
    """DDPG / TD3: the actor (tanh-bounded); its target follows once fitted."""

    def after_fit() -> None:
        model.actor_target.load_state_dict(model.actor.state_dict())

    return StudentActor(model.actor, model.actor.parameters, after_fit)


STUDENTS: dict[str, Callable[[Any], StudentActor]] = {
    "ppo": _gaussian_mean,
    "a2c": _gaussian_mean,
    "ddpg": _deterministic_actor,
    "td3": _deterministic_actor,
}


def check_algo(algo: str) -> None:
    if algo not in STUDENTS:
        raise ConfigError(f"dagger trains a student of {sorted(STUDENTS)}, not {algo!r}")


# ---- the stage -----------------------------------------------------------------------------------
def _returns(rewards: list[float], gamma: float) -> list[float]:
    """Discounted returns of one finished episode."""
    out, g = [], 0.0
    for r in reversed(rewards):
        g = r + gamma * g
        out.append(g)
    return out[::-1]


class DaggerStage:
    """The stage on one model: its student, the teacher and the aggregated dataset, which the
    anchor (``anchor``) goes on using while the algorithm learns."""

    def __init__(self, model: Any, algo: str, cfg: Dagger, seed: int) -> None:
        from sim2real.train.distill import get_teacher

        check_algo(algo)
        self.model, self.algo, self.cfg = model, algo, cfg
        self.student = STUDENTS[algo](model)
        venv = model.get_env()
        decoder = venv.get_attr("decoder", [0])[0] if venv.has_attr("decoder") else None
        self.teacher = get_teacher(cfg.teacher, decoder)
        if not self.teacher.continuous:
            raise ConfigError(f"dagger teacher {cfg.teacher!r} has discrete actions")
        self.rng = np.random.default_rng(seed)
        self.optimizer = th.optim.Adam(list(self.student.parameters()), lr=cfg.learning_rate)
        self.seen: list[np.ndarray] = []
        self.labels: list[np.ndarray] = []
        self._kept = 0

    def normalise(self, raw: np.ndarray) -> th.Tensor:
        vn = self.model.get_vec_normalize_env()
        x = vn.normalize_obs(raw) if vn is not None else raw
        return th.as_tensor(np.asarray(x, dtype=np.float32), device=self.model.device)

    def label(self, raw: np.ndarray) -> np.ndarray:
        """The teacher's actions for the envs' current states (``raw``: their observations)."""
        privileged = self.model.get_env().env_method("privileged_state")
        label = np.stack([self.teacher.action(p) for p in privileged]).astype(np.float32)
        self.seen.append(np.array(raw, dtype=np.float32, copy=True))
        self.labels.append(label)
        self._kept += len(label)
        while self._kept - len(self.labels[0]) >= self.cfg.dataset_size:  # the newest are kept
            self._kept -= len(self.labels.pop(0))
            self.seen.pop(0)
        return label

    def fit(self, updates: int) -> float:
        """``updates`` minibatches of the squared error to every label so far; the mean loss of
        the last tenth."""
        x = self.normalise(np.concatenate(self.seen))  # this moment's normalisation statistics
        y = th.as_tensor(np.concatenate(self.labels), device=x.device)
        losses = []
        for _ in range(updates):
            idx = th.as_tensor(self.rng.integers(0, len(x), self.cfg.batch_size), device=x.device)
            loss = functional.mse_loss(self.student.act(x[idx]), y[idx])
            self.optimizer.zero_grad()
            loss.backward()
            self.optimizer.step()
            losses.append(float(loss.item()))
        self.student.after_fit()
        return float(np.mean(losses[-max(len(losses) // 10, 1) :]))

    def run(self) -> dict[str, Any]:
        """The rounds, then the critic of the fixed student (see the module docstring)."""
        model, cfg = self.model, self.cfg
        venv, vn = model.get_env(), model.get_vec_normalize_env()
        n_envs = venv.num_envs
        off_policy = getattr(model, "replay_buffer", None) is not None
        gamma = float(model.gamma)
        value_obs: list[np.ndarray] = []
        value_returns: list[float] = []
        episode_obs: list[list[np.ndarray]] = [[] for _ in range(n_envs)]
        episode_rewards: list[list[float]] = [[] for _ in range(n_envs)]
        rounds: list[dict[str, Any]] = []
        t0 = time.perf_counter()
        obs = venv.reset()
        raw = vn.get_original_obs() if vn is not None else obs
        for it in range(cfg.iterations):
            by_teacher = it < cfg.teacher_iterations
            successes: list[bool] = []
            for _ in range(cfg.steps_per_iteration):
                label = self.label(raw)
                action = label if by_teacher else self._explore(raw)
                new_obs, rewards, dones, infos = venv.step(action)
                new_raw = vn.get_original_obs() if vn is not None else new_obs
                raw_rewards = vn.get_original_reward() if vn is not None else rewards
                next_raw = np.array(new_raw, copy=True)
                for i, done in enumerate(dones):
                    episode_obs[i].append(np.array(raw[i], dtype=np.float32, copy=True))
                    episode_rewards[i].append(float(raw_rewards[i]))
                    if not done:
                        continue
                    term = infos[i].get("terminal_observation")
                    if term is not None:
                        next_raw[i] = vn.unnormalize_obs(term) if vn is not None else term
                    if not by_teacher:
                        successes.append(bool(infos[i].get("is_success", False)))
                        value_obs.extend(episode_obs[i])
                        value_returns.extend(_returns(episode_rewards[i], gamma))
                    episode_obs[i], episode_rewards[i] = [], []
                if off_policy:
                    model.replay_buffer.add(
                        raw, next_raw, model.policy.scale_action(action), raw_rewards, dones, infos
                    )
                raw = new_raw
            loss = self.fit(cfg.updates_per_iteration)
            rate = float(np.mean(successes)) if successes else None
            rounds.append(
                {
                    "iteration": it,
                    "acted": "teacher" if by_teacher else "student",
                    "episodes": len(successes),
                    "student_success_rate": rate,
                    "imitation_mse": loss,
                    "labels": len(self.seen) * n_envs,
                    "wall_s": round(time.perf_counter() - t0, 1),
                }
            )
            model.logger.record("dagger/imitation_mse", loss)
            if rate is not None:
                model.logger.record("dagger/student_success_rate", rate)
            model.logger.dump(it)
        collected = cfg.iterations * cfg.steps_per_iteration * n_envs
        model.num_timesteps += collected  # they are env steps of this run
        imitate_s = time.perf_counter() - t0
        t1 = time.perf_counter()
        critic = _train_critic(
            model, self.algo, cfg, self.normalise, value_obs, value_returns, self.rng
        )
        venv.reset()  # learn() starts its episodes afresh
        return {
            "teacher": cfg.teacher,
            "transitions": collected,
            "iterations": rounds,
            "final_student_success_rate": rounds[-1]["student_success_rate"],
            **critic,
            "imitate_s": round(imitate_s, 1),
            "critic_s": round(time.perf_counter() - t1, 1),
        }

    def _explore(self, raw: np.ndarray) -> np.ndarray:
        with th.no_grad():
            mean = self.student.act(self.normalise(raw)).cpu().numpy()
        noise = self.cfg.noise_sigma * self.rng.standard_normal(mean.shape)
        return np.clip(mean + noise, -1.0, 1.0).astype(np.float32)

    def anchor(self) -> ImitationAnchor | None:
        """The callback that keeps imitating while the algorithm learns; None without one."""
        return ImitationAnchor(self) if self.cfg.anchor_every else None


def dagger(model: Any, algo: str, cfg: Dagger, seed: int) -> dict[str, Any]:
    """Run the stage on a new ``model`` of ``algo`` (see the module docstring); its figures."""
    return DaggerStage(model, algo, cfg, seed).run()


class ImitationAnchor(BaseCallback):
    """DAgger beside the algorithm's own updates: each env step the teacher labels the states
    the learner now visits; every ``anchor_every`` steps ``anchor_updates`` minibatches of the
    imitation loss pull the student's action back towards the teacher's.

    The minibatches run when a rollout starts, after the algorithm's update and before new
    data: run between a rollout and PPO's update on it, they moved the policy away from the
    one that collected it (PPO's approximate KL 0.4-1.1, 90 % of its ratios clipped), and the
    student fell from 95.5 % to 66.5 % in 120k steps."""

    def __init__(self, stage: DaggerStage) -> None:
        super().__init__()
        self.stage = stage
        self._since = 0

    def _on_training_start(self) -> None:  # the envs' first states; then each step's
        self._label_current()

    def _on_step(self) -> bool:
        self._label_current()
        self._since += self.training_env.num_envs
        return True

    def _on_rollout_start(self) -> None:
        if self._since >= self.stage.cfg.anchor_every:
            self._since = 0
            loss = self.stage.fit(self.stage.cfg.anchor_updates)
            self.logger.record("dagger/anchor_mse", loss)

    def _label_current(self) -> None:
        vn = self.model.get_vec_normalize_env()
        raw = vn.get_original_obs() if vn is not None else self.model._last_obs
        if isinstance(raw, np.ndarray):  # a state student's flat observation
            self.stage.label(raw)


def _train_critic(
    model: Any,
    algo: str,
    cfg: Dagger,
    normalise: Callable[[np.ndarray], th.Tensor],
    value_obs: list[np.ndarray],
    value_returns: list[float],
    rng: np.random.Generator,
) -> dict[str, Any]:
    """The critic of the fixed student: Q updates (off-policy) or value regression (on-policy)."""
    if cfg.critic_updates and hasattr(model, "replay_buffer"):
        from sim2real.train.warmstart import CRITIC_UPDATES

        update = CRITIC_UPDATES[algo]
        losses = [update(model, int(model.batch_size), k) for k in range(cfg.critic_updates)]
        tenth = max(len(losses) // 10, 1)
        return {
            "critic_updates": cfg.critic_updates,
            "critic_initial_loss": float(np.mean(losses[:tenth])),
            "critic_final_loss": float(np.mean(losses[-tenth:])),
        }
    if not cfg.value_epochs or not value_obs or not hasattr(model.policy, "predict_values"):
        return {}
    vn = model.get_vec_normalize_env()
    returns = np.asarray(value_returns, dtype=np.float32)
    if vn is not None and vn.norm_reward:  # the scale PPO's value head learns in
        returns = returns / np.sqrt(vn.ret_rms.var + vn.epsilon)
    x = normalise(np.stack(value_obs))
    y = th.as_tensor(returns, device=x.device)[:, None]
    policy = model.policy
    params = [
        *policy.vf_features_extractor.parameters(),
        *policy.mlp_extractor.value_net.parameters(),
        *policy.value_net.parameters(),
    ]
    optimizer = th.optim.Adam(params, lr=cfg.learning_rate)
    batch = cfg.batch_size
    first = last = float("nan")
    for epoch in range(cfg.value_epochs):
        order = th.as_tensor(rng.permutation(len(x)), device=x.device)
        total = 0.0
        for start in range(0, len(order), batch):
            idx = order[start : start + batch]
            loss = functional.mse_loss(policy.predict_values(x[idx]), y[idx])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total += float(loss.item()) * len(idx)
        last = total / len(order)
        if epoch == 0:
            first = last
    return {"value_epochs": cfg.value_epochs, "value_first_mse": first, "value_final_mse": last}
