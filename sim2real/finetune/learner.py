"""The learner process: the SB3 model, its replay buffer, critic and optimisers, off the loop.

The control loop must never wait for a gradient. So the learner is another process (a
``deploy.child.ChildProcess``: started fresh, not forked, since the loop's process holds threads,
a serial port and possibly real-time priority), at a lower CPU priority (``nice``) and normal
scheduling. One channel carries the loop's transitions (posted: the loop never waits) and
commands, in order, so a checkpoint holds exactly the transitions sent before it; the actor's
weights come back through shared memory (one flat float32 vector and a version counter under the
runtime's sequence lock, which the loop reads without waiting), so the loop picks up new weights
between periods without blocking.

The learner ignores SIGINT and SIGTERM (the loop decides: it parks the arm, asks for a
checkpoint, then stops it) and dies with its parent, as every child of the runtime does.

``--mix-sim-buffer``: a second buffer of sim transitions, collected at start-up from the source
run's own env with its own actor (exploring), is sampled 50/50 with the online buffer in every
batch (symmetric sampling, as in RLPD, Ball et al. 2023).
"""

from __future__ import annotations

import io
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sim2real.deploy import child
from sim2real.errors import Sim2RealError
from sim2real.finetune.defaults import ACTOR_UPDATES
from sim2real.finetune.relabel import EpisodeIndex, GoalFields, Relabeler

log = logging.getLogger(__name__)

MAX_ACTOR_FLOATS = 4_000_000  # the shared actor vector (16 MB): far above any MLP we train
TRAIN_CHUNK = 4  # gradient steps between two looks at the queue
AWR_MAX_WEIGHT = 20.0  # advantage-weighted regression: one row's weight at most (AWAC's clip)
READY_TIMEOUT_S = 300.0  # loading torch + SB3 (+ a sim buffer) on a loaded 2-core machine
# the weights block: a float64 header [lock, version, gradient updates, actor size], then the
# actor as float32
_LOCK, _VERSION, _UPDATES, _SIZE = range(4)
_W_HEADER = 4


class LearnerError(Sim2RealError):
    """The learner process failed or went away."""


@dataclass(frozen=True)
class SimBufferConfig:
    env_id: str
    env_kwargs: dict[str, Any]
    spec: Any  # ArmSpec (picklable)
    steps: int = 5000
    seed: int = 0


@dataclass(frozen=True)
class LearnerConfig:
    algo: str
    source_algo: str
    model_zip: str
    obs_stats: dict[str, Any] | None
    replay_npz: str | None = None  # resume: the online transitions so far
    resume: bool = False  # model_zip is our own checkpoint (already in ``algo``'s form)
    capacity: int = 200_000
    batch_size: int | None = None  # None: the source run's
    learning_starts: int = 200  # online transitions before the first gradient step
    utd: float = 1.0  # gradient steps per online transition
    publish_every: int = 20  # env steps between two weight publications
    nice: int = 10
    seed: int = 0
    sim_buffer: SimBufferConfig | None = None
    # critic warm-up: online transitions before the actor's first update (the critic first
    # fits the new plant's returns; an actor following a miscalibrated critic degrades first)
    actor_starts: int = 0
    learning_rate: float | None = None  # None: the source run's
    action_rate_penalty: float = 0.0  # the source run's training shaping (sim buffer rewards)
    # hindsight goals: this share of every online batch gets a goal reached later in its episode
    relabel_ratio: float = 0.0
    goal_fields: GoalFields | None = None
    # imitation minibatches towards ``anchor_zip``'s actor per gradient step (0: none). A source
    # trained with a DAgger anchor keeps one here, its teacher the source actor itself (the
    # privileged teacher needs the simulator's truth): without it the algorithm's own updates
    # undo the imitation (``docs/studies/pick.md``: DDPG without the anchor fell to 0 %).
    anchor_ratio: float = 0.0
    anchor_zip: str | None = None  # the source's model (a resumed run's model_zip is its own)
    # how the actor learns (``ACTOR_UPDATES``): "critic", the algorithm's own gradient through
    # the critic; "success", regression on the actions of the arm's own successful episodes;
    # "advantage", on every action taken, weighted by the critic's advantage (AWAC)
    actor_update: str = "critic"
    imitation_ratio: float = 1.0  # "success", "advantage": imitation minibatches per step
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.actor_update not in ACTOR_UPDATES:
            raise LearnerError(
                f"actor update {self.actor_update!r} is not one of {sorted(ACTOR_UPDATES)}"
            )
        if not (math.isfinite(self.imitation_ratio) and self.imitation_ratio > 0):
            raise LearnerError(f"imitation ratio {self.imitation_ratio!r} must be a number > 0")
        if not (math.isfinite(self.anchor_ratio) and self.anchor_ratio >= 0):
            raise LearnerError(f"anchor ratio {self.anchor_ratio!r} must be a number >= 0")
        if self.anchor_ratio > 0 and not self.anchor_zip:
            raise LearnerError("an anchor ratio > 0 needs the source model (anchor_zip)")


class RewardShaper:
    """The source run's training-only action-rate penalty, ``-coef * ||a_t - a_{t-1}||^2`` on the
    normalised actions the policy chose (``train.wrappers.ActionRatePenalty``): the critic learned
    its returns with it, so the online rewards it learns from carry it too. ``reset`` at every
    episode start (the first step's previous action is zero, as in training)."""

    def __init__(self, coef: float) -> None:
        if not (math.isfinite(coef) and coef >= 0):
            raise LearnerError(f"action-rate penalty {coef!r} must be a number >= 0")
        self.coef = float(coef)
        self._prev: np.ndarray | None = None

    def reset(self) -> None:
        self._prev = None

    def __call__(self, reward: float, action: np.ndarray) -> float:
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        prev = np.zeros_like(a) if self._prev is None else self._prev
        self._prev = a
        return float(reward) - self.coef * float(np.sum((a - prev) ** 2))


# ---- the learner's side ------------------------------------------------------------------------
def _mixed_buffer_class() -> Any:
    import torch as th
    from stable_baselines3.common.buffers import ReplayBuffer

    class MixedReplayBuffer(ReplayBuffer):
        """Online transitions; with ``sim`` set, half of every batch comes from it. With
        ``relabel`` set, a share of the online rows get a goal from later in their episode."""

        sim: ReplayBuffer | None = None
        relabel: Relabeler | None = None
        episodes: EpisodeIndex | None = None
        _rng: np.random.Generator

        def use_relabeler(self, relabeler: Relabeler) -> None:
            self.relabel = relabeler
            self._rng = np.random.default_rng(np.random.randint(2**31))  # seeded with the model
            self.episodes = EpisodeIndex(self.buffer_size)
            n = self.size()
            start = self.pos if self.full else 0
            for k in range(n):  # rows in insertion order
                row = (start + k) % self.buffer_size
                self.episodes.add(row, self.observations[row, 0], self.next_observations[row, 0])

        def add(self, obs: Any, next_obs: Any, action: Any, reward: Any, done: Any,
                infos: Any) -> None:  # fmt: skip
            if self.episodes is not None:
                self.episodes.add(self.pos, obs[0], next_obs[0])
            super().add(obs, next_obs, action, reward, done, infos)

        def _get_samples(self, batch_inds: np.ndarray, env: Any = None) -> Any:
            if self.relabel is None or self.episodes is None:
                return super()._get_samples(batch_inds, env)
            from stable_baselines3.common.type_aliases import ReplayBufferSamples

            obs = self.observations[batch_inds, 0].copy()
            next_obs = self.next_observations[batch_inds, 0].copy()
            rewards = self.rewards[batch_inds, 0].copy()
            pick = np.flatnonzero(self._rng.random(len(batch_inds)) < self.relabel.ratio)
            future = self.episodes.future(batch_inds[pick], self._rng)
            ok = future >= 0
            rows, future = pick[ok], future[ok]
            if len(rows):
                o, n = obs[rows], next_obs[rows]
                rewards[rows] = self.relabel.relabel(
                    o, n, self.actions[batch_inds[rows], 0], self.next_observations[future, 0]
                )
                obs[rows], next_obs[rows] = o, n
            data = (obs, self.actions[batch_inds, 0], next_obs,
                    self.dones[batch_inds, 0].reshape(-1, 1),
                    rewards.reshape(-1, 1))  # fmt: skip
            return ReplayBufferSamples(*tuple(map(self.to_torch, data)))

        def sample(self, batch_size: int, env: Any = None) -> Any:
            if self.sim is None or self.sim.size() == 0:
                return super().sample(batch_size, env)
            n_online = batch_size // 2
            online = super().sample(n_online, env)
            offline = self.sim.sample(batch_size - n_online, env)
            return type(online)(
                *(  # type: ignore[arg-type]
                    None if a is None or b is None else th.cat([a, b])
                    for a, b in zip(online, offline, strict=True)
                )
            )

    return MixedReplayBuffer


class Learner:
    """The SB3 model and its buffers, inside the learner process."""

    def __init__(self, cfg: LearnerConfig) -> None:
        import torch as th
        from stable_baselines3.common.logger import Logger

        from sim2real.finetune.actor import ObsNormalizer, actor_arrays
        from sim2real.train.algos import get_algo

        th.set_num_threads(1)
        self.cfg = cfg
        cls = get_algo(cfg.algo).cls
        self.model = cls.load(  # type: ignore[attr-defined]
            cfg.model_zip,
            device="cpu",
            custom_objects={
                "buffer_size": 1,
                "learning_starts": 0,
                "replay_buffer_class": None,
                "replay_buffer_kwargs": {},
            },
        )
        model = self.model
        if not cfg.resume and cfg.source_algo != cfg.algo:  # ddpg -> td3: TD3's update rule
            model.policy_delay, model.target_policy_noise, model.target_noise_clip = 2, 0.2, 0.5
        model.set_logger(Logger(folder=None, output_formats=[]))
        model.set_random_seed(cfg.seed)
        if cfg.learning_rate is not None:
            lr = float(cfg.learning_rate)
            model.learning_rate = lr
            model.lr_schedule = lambda _progress: lr
        self.policy_delay = int(getattr(model, "policy_delay", 1))
        self.start_updates = int(model._n_updates)
        self.batch_size = int(cfg.batch_size or model.batch_size)
        buffer_cls = _mixed_buffer_class()
        self.buffer = buffer_cls(
            cfg.capacity, model.observation_space, model.action_space, device="cpu", n_envs=1,
            handle_timeout_termination=False,
        )  # fmt: skip
        model.replay_buffer = self.buffer
        if cfg.replay_npz is not None:
            self._load_replay(cfg.replay_npz)
        self.normalizer = ObsNormalizer.from_stats(cfg.obs_stats)
        self.kind, arrays = actor_arrays(model)
        self.shapes = [a.shape for a in arrays]
        noise = getattr(model, "action_noise", None)
        sigma = getattr(getattr(noise, "base_noise", noise), "_sigma", None)
        self.noise_std = float(np.mean(sigma)) if sigma is not None else 0.1
        if cfg.relabel_ratio > 0:
            if cfg.goal_fields is None:
                raise LearnerError("goal relabelling needs the task's goal fields")
            nz = self.normalizer
            self.buffer.use_relabeler(Relabeler(
                cfg.goal_fields, cfg.relabel_ratio,
                None if nz is None else nz.mean, None if nz is None else np.sqrt(nz.var + nz.epsilon),
                cfg.action_rate_penalty,
            ))  # fmt: skip
        if cfg.sim_buffer is not None:
            self.buffer.sim = self._collect_sim(cfg.sim_buffer)
        self.imitation_updates = 0
        # the arm's own successful episodes: a row mask over the buffer, and the rows of the
        # episode in flight (an episode counts once its end says it succeeded)
        self._good = np.zeros(cfg.capacity, bool)
        self._good_rows: np.ndarray | None = None  # np.flatnonzero(self._good), cached
        self._episode_rows: list[int] = []
        self.own_imitation_updates = 0
        self._own_debt = 0.0  # own-data imitation minibatches owed (the ratio's fractions)
        # how the actor learns from the arm's own data, by ``actor_update`` (None: the critic)
        self._own_imitation = {
            "critic": None,
            "success": self._imitate_successes,
            "advantage": self._imitate_advantage,
        }[cfg.actor_update]
        self._rng = np.random.default_rng(cfg.seed)
        if cfg.replay_npz is not None:
            self._load_successes(cfg.replay_npz)
        self._anchor: Any = None  # the source actor, frozen
        self._anchor_debt = 0.0  # imitation minibatches owed (the ratio's fractions)
        if cfg.actor_update != "critic" and self.kind != "deterministic":
            raise LearnerError(
                f"--actor-update {cfg.actor_update} needs a deterministic actor (DDPG/TD3), "
                f"not {self.kind}"
            )
        if cfg.anchor_ratio > 0:
            if self.kind != "deterministic":
                raise LearnerError(
                    f"the source anchor needs a deterministic actor, not {self.kind}"
                )
            source = cls.load(cfg.anchor_zip, device="cpu", custom_objects={"buffer_size": 1})  # type: ignore[attr-defined]
            self._anchor = source.actor.eval()
            for param in self._anchor.parameters():
                param.requires_grad_(False)

    @property
    def updates(self) -> int:
        return int(self.model._n_updates)

    def flat_actor(self) -> np.ndarray:
        from sim2real.finetune.actor import actor_arrays, flatten

        return flatten(actor_arrays(self.model)[1])

    def add(self, obs: np.ndarray, action: np.ndarray, reward: float, next_obs: np.ndarray,
            done: bool) -> None:  # fmt: skip
        row = int(self.buffer.pos)
        if self._good[row]:  # a full buffer overwrites it
            self._good[row] = False
            self._good_rows = None
        self._episode_rows.append(row)
        self.buffer.add(
            obs[None], next_obs[None], np.asarray(action, np.float32)[None],
            np.asarray([reward], np.float32), np.asarray([float(done)], np.float32), [{}],
        )  # fmt: skip

    def end_episode(self, success: bool) -> None:
        """The episode whose transitions were added since the last call ended: its rows join
        the successful ones if it succeeded. A lost episode ends as a failure."""
        if success and self._episode_rows:
            self._good[self._episode_rows] = True
            self._good_rows = None
        self._episode_rows = []

    @property
    def successful_transitions(self) -> int:
        return int(self._good.sum())

    def train(self, steps: int) -> None:
        """``steps`` gradient steps; before ``actor_starts`` online transitions, the critic's
        only (its target follows by Polyak averaging, the actor and its target stay put). With
        ``actor_update`` "success" or "advantage" the critic learns alone throughout, and the
        actor imitates the successful episodes, or every action by its advantage."""
        model = self.model
        if self._own_imitation is not None:  # a deterministic actor: DDPG/TD3 (checked)
            self._critic_only(steps, follow_actor=True)
            self._imitate(steps)
            self._own_imitation(steps)
            return
        if self.buffer.size() >= self.cfg.actor_starts or not hasattr(model, "policy_delay"):
            model.policy_delay = self.policy_delay
            model.train(gradient_steps=steps, batch_size=self.batch_size)
            self._imitate(steps)
            return
        self._critic_only(steps)

    def _critic_only(self, steps: int, follow_actor: bool = False) -> None:
        """Critic updates alone. ``follow_actor``: the actor's target follows an actor that
        learns by other means, so the critic's bootstrap values the actor that acts."""
        from stable_baselines3.common.utils import polyak_update

        model = self.model
        for _ in range(steps):
            # an actor update happens when _n_updates % policy_delay == 0: never, here
            model.policy_delay = int(model._n_updates) + 2
            model.train(gradient_steps=1, batch_size=self.batch_size)
            polyak_update(model.critic.parameters(), model.critic_target.parameters(), model.tau)
            if follow_actor:
                polyak_update(model.actor.parameters(), model.actor_target.parameters(), model.tau)
        model.policy_delay = self.policy_delay

    def _imitate_successes(self, steps: int) -> None:
        """``imitation_ratio`` minibatches per gradient step: the actor's action on states of
        the successful episodes regressed on the action taken there (squared error)."""
        if self._good_rows is None:
            self._good_rows = np.flatnonzero(self._good)
        rows = self._good_rows
        if len(rows) == 0:
            return
        import torch as th

        n, self._own_debt = _owed(self._own_debt, self.cfg.imitation_ratio, steps)
        actor, b = self.model.actor, self.buffer

        def loss() -> Any:
            pick = rows[self._rng.integers(len(rows), size=self.batch_size)]
            obs = b.to_torch(b.observations[pick, 0])
            return th.nn.functional.mse_loss(actor(obs), b.to_torch(b.actions[pick, 0]))

        self._actor_steps(n, loss)
        self.own_imitation_updates += n

    def _imitate_advantage(self, steps: int) -> None:
        """``imitation_ratio`` minibatches per gradient step of advantage-weighted regression
        (AWAC, Nair et al. 2020): the actor regresses on every action taken, each weighted by
        ``exp(A / std(A))`` (at most ``AWR_MAX_WEIGHT``), A = Q(s, a) - Q(s, actor(s)) from the
        critic learning on the arm. It moves only towards actions the arm took, so a critic fitted
        on minutes of data cannot pull it where no data is (with ``--mix-sim-buffer``, half of each
        batch is the simulator's)."""
        import torch as th

        n, self._own_debt = _owed(self._own_debt, self.cfg.imitation_ratio, steps)
        actor, critic = self.model.actor, self.model.critic

        def loss() -> Any:
            batch = self.buffer.sample(self.batch_size)
            obs, taken = batch.observations, batch.actions
            with th.no_grad():
                adv = critic.q1_forward(obs, taken) - critic.q1_forward(obs, actor(obs))
                scale = adv.std(unbiased=False) + 1e-6
                weight = th.exp(adv / scale).clamp(max=AWR_MAX_WEIGHT)
            err = ((actor(obs) - taken) ** 2).sum(dim=-1, keepdim=True)
            return (weight * err).mean()

        self._actor_steps(n, loss)
        self.own_imitation_updates += n

    def _imitate(self, steps: int) -> None:
        """``anchor_ratio`` imitation minibatches per gradient step: the actor's action on
        buffer states regressed on the source actor's (squared error), as ``ImitationAnchor``
        does in training, after the algorithm's own updates."""
        if self._anchor is None:
            return
        import torch as th

        n, self._anchor_debt = _owed(self._anchor_debt, self.cfg.anchor_ratio, steps)
        actor = self.model.actor

        def loss() -> Any:
            obs = self.buffer.sample(self.batch_size).observations
            with th.no_grad():
                target = self._anchor(obs)
            return th.nn.functional.mse_loss(actor(obs), target)

        self._actor_steps(n, loss)
        self.imitation_updates += n

    def _actor_steps(self, n: int, loss: Callable[[], Any]) -> None:
        """``n`` steps of the actor's own optimiser, each on a fresh minibatch's ``loss()``."""
        optimizer = self.model.actor.optimizer
        for _ in range(n):
            value = loss()
            optimizer.zero_grad()
            value.backward()
            optimizer.step()

    @staticmethod
    def action_rate_penalty(config: dict[str, Any]) -> float:
        """The source run's training-only reward shaping (``train.action_rate_penalty``): the
        critic learned returns with it, so online rewards must carry it too."""
        return float(dict(config.get("train") or {}).get("action_rate_penalty", 0.0) or 0.0)

    def save(self, model_paths: list[str], replay_path: str) -> None:
        from hardware.atomic import atomic_write_bytes

        buf = io.BytesIO()
        self.model.save(buf)
        for path in model_paths:
            atomic_write_bytes(path, buf.getvalue())
        n = self.buffer.size()
        out = io.BytesIO()
        np.savez(
            out,
            obs=self.buffer.observations[:n, 0],
            next_obs=self.buffer.next_observations[:n, 0],
            actions=self.buffer.actions[:n, 0],
            rewards=self.buffer.rewards[:n, 0],
            dones=self.buffer.dones[:n, 0],
            pos=np.asarray(self.buffer.pos),
            full=np.asarray(self.buffer.full),
            successful_rows=np.flatnonzero(self._good[: self.buffer.buffer_size]),
        )
        atomic_write_bytes(replay_path, out.getvalue())

    def _load_replay(self, path: str) -> None:
        with np.load(path) as data:
            n = len(data["obs"])
            if n > self.buffer.buffer_size:
                raise LearnerError(f"{path}: {n} transitions, more than the buffer's capacity")
            b = self.buffer
            b.observations[:n, 0] = data["obs"]
            b.next_observations[:n, 0] = data["next_obs"]
            b.actions[:n, 0] = data["actions"]
            b.rewards[:n, 0] = data["rewards"]
            b.dones[:n, 0] = data["dones"]
            b.full = bool(data["full"]) and n == b.buffer_size
            b.pos = int(data["pos"]) if b.full else n % b.buffer_size

    def _load_successes(self, path: str) -> None:
        with np.load(path) as data:
            if "successful_rows" in data.files:
                self._good[data["successful_rows"]] = True

    def _collect_sim(self, sc: SimBufferConfig) -> Any:
        """Sim transitions from the source run's env, acted by the source actor (exploring)."""
        from stable_baselines3.common.buffers import ReplayBuffer

        import sim2real.envs as envs
        from sim2real.finetune.actor import NumpyActor

        actor = NumpyActor(self.kind, self.shapes, self.flat_actor(), self.normalizer,
                           self.noise_std)  # fmt: skip
        rng = np.random.default_rng(sc.seed)
        env = envs.make(sc.env_id, **{**sc.env_kwargs, "spec": sc.spec})
        sim = ReplayBuffer(
            sc.steps, self.model.observation_space, self.model.action_space, device="cpu",
            n_envs=1, handle_timeout_termination=False,
        )  # fmt: skip
        shaper = RewardShaper(self.cfg.action_rate_penalty)
        norm = self.normalizer or (lambda o: np.asarray(o, np.float32))
        t0 = time.monotonic()
        try:
            obs, _ = env.reset(seed=sc.seed)
            for _ in range(sc.steps):
                action = actor.explore(obs, rng)
                nxt, reward, terminated, truncated, _ = env.step(action)
                shaped = shaper(float(reward), action)
                sim.add(
                    norm(obs)[None], norm(nxt)[None], action[None],
                    np.asarray([shaped], np.float32), np.asarray([float(terminated)], np.float32),
                    [{}],
                )  # fmt: skip
                obs = nxt
                if terminated or truncated:
                    obs, _ = env.reset()
                    shaper.reset()
        finally:
            env.close()
        log.info("sim buffer: %d transitions in %.1f s", sim.size(), time.monotonic() - t0)
        return sim


def _owed(debt: float, ratio: float, steps: int) -> tuple[int, float]:
    """Minibatches due for ``ratio`` per gradient step over ``steps``, and the fraction carried."""
    total = debt + ratio * steps
    return int(total), total % 1.0


class _Weights:
    """The actor's weights in shared memory: the learner publishes, the loop reads newer ones
    without waiting (a read during a write is skipped until the next period)."""

    def __init__(self, name: str | None = None) -> None:
        self.block = child.SharedBlock(8 * _W_HEADER + 4 * MAX_ACTOR_FLOATS, name)
        self.header = self.block.array(_W_HEADER)
        self.actor = self.block.array(MAX_ACTOR_FLOATS, np.float32, offset=8 * _W_HEADER)
        if name is None:
            self.header[:] = 0.0

    def publish(self, flat: np.ndarray) -> None:
        with child.seqlock(self.header, _LOCK):
            self.actor[: flat.size] = flat
            self.header[_SIZE] = flat.size
            self.header[_VERSION] += 1

    def read(self) -> tuple[int, np.ndarray] | None:
        """(version, a copy of the actor), or None while the learner writes it."""
        h = self.header
        return child.read_consistent(
            h, lambda: (int(h[_VERSION]), self.actor[: int(h[_SIZE])].copy()), _LOCK, tries=1
        )

    def close(self) -> None:
        del self.header, self.actor  # the views go before the buffer closes
        self.block.close()


def _serve(channel: child.ChildChannel) -> None:
    """The learner process: load, publish the first weights, then learn until stopped."""
    cfg, weights_name = channel.job
    learner = Learner(cfg)
    flat = learner.flat_actor()
    if flat.size > MAX_ACTOR_FLOATS:
        raise LearnerError(f"the actor has {flat.size} weights; at most {MAX_ACTOR_FLOATS}")
    weights = _Weights(weights_name)
    weights.publish(flat)
    weights.header[_UPDATES] = learner.updates
    channel.ready(
        {"kind": learner.kind, "shapes": learner.shapes, "size": int(flat.size),
         "noise_std": learner.noise_std, "online": int(learner.buffer.size()),
         "updates": learner.updates,
         "sim": int(learner.buffer.sim.size()) if learner.buffer.sim else 0}
    )  # fmt: skip
    try:
        _learn(learner, cfg, channel, weights)
    finally:
        weights.close()


def _requests(channel: child.ChildChannel, wait_s: float) -> list[Any]:
    """What the loop sent: the first within ``wait_s``, then up to 255 more already there."""
    first = channel.receive(wait_s)
    requests = [] if first is None else [first]
    while requests and len(requests) < 256:
        more = channel.receive(0.0)
        if more is None:
            break
        requests.append(more)
    return requests


def _learn(
    learner: Learner, cfg: LearnerConfig, channel: child.ChildChannel, weights: _Weights
) -> None:
    pending = 0.0  # gradient steps owed (utd per online transition once warm)
    cap = max(cfg.utd * cfg.publish_every * 5, TRAIN_CHUNK)
    since_publish = 0
    trained_since_publish = False
    while not channel.stopping:
        can_train = learner.buffer.size() >= cfg.learning_starts and pending >= 1
        for request in _requests(channel, 0.0 if can_train else 0.2):
            if request.op == "t":
                learner.add(*request.args)
                since_publish += 1
                if learner.buffer.size() >= cfg.learning_starts:
                    pending = min(pending + cfg.utd, cap)
            elif request.op == "e":
                learner.end_episode(*request.args)
            elif request.op == "save":
                learner.save(*request.args)
                channel.answer((learner.updates, int(learner.buffer.size())))
            else:
                raise LearnerError(f"unknown request {request.op!r}; valid: ['e', 'save', 't']")
        if channel.stopping:
            return
        if learner.buffer.size() >= cfg.learning_starts and pending >= 1:
            k = min(int(pending), TRAIN_CHUNK)
            learner.train(k)
            pending -= k
            weights.header[_UPDATES] = learner.updates
            trained_since_publish = True
        if since_publish >= cfg.publish_every and trained_since_publish:
            weights.publish(learner.flat_actor())
            since_publish = 0
            trained_since_publish = False


# ---- the loop's side ---------------------------------------------------------------------------
class LearnerHandle:
    """The loop's end: send transitions, take new weights without blocking, checkpoint, stop."""

    def __init__(self, cfg: LearnerConfig) -> None:
        self.cfg = cfg
        self._weights = _Weights()
        self._child = child.ChildProcess(
            "learner process", "sim2real.finetune.learner", (cfg, self._weights.block.name),
            start_timeout_s=READY_TIMEOUT_S, stop_timeout_s=10.0, nice=cfg.nice,
            error=LearnerError,
        )  # fmt: skip
        self._seen = 0
        self._closed = False
        self.info: dict[str, Any] = {}
        self._child.launch()  # it loads torch while the caller goes on

    @property
    def pid(self) -> int | None:
        return self._child.pid

    @property
    def updates(self) -> int:
        return int(self._weights.header[_UPDATES])

    def wait_ready(self, timeout_s: float = READY_TIMEOUT_S) -> dict[str, Any]:
        self.info = dict(self._child.wait_ready(timeout_s))
        return self.info

    def initial_weights(self) -> np.ndarray:
        """The actor the learner published when it became ready."""
        while True:
            read = self._weights.read()
            if read is not None:
                self._seen, flat = read
                return flat
            self._child.check_alive()
            time.sleep(0.001)  # it is publishing a newer one right now

    def new_weights(self) -> np.ndarray | None:
        """The newest published actor, or None if there is none newer or the learner is
        writing it right now (the loop never waits: it tries again next period)."""
        if int(self._weights.header[_VERSION]) == self._seen:
            return None
        read = self._weights.read()
        if read is None:
            return None
        self._seen, flat = read
        return flat

    def send(self, obs: np.ndarray, action: np.ndarray, reward: float, next_obs: np.ndarray,
             done: bool) -> None:  # fmt: skip
        self._child.post("t", obs, action, float(reward), next_obs, bool(done))

    def end_episode(self, success: bool) -> None:
        """The transitions sent since the last call were one episode, and how it ended."""
        self._child.post("e", bool(success))

    def check(self) -> None:
        """Between episodes: a learner that failed or died is an error here, in one line."""
        self._child.check_alive()

    def checkpoint(self, model_paths: list[str], replay_path: str, timeout_s: float = 120.0
                   ) -> tuple[int, int]:  # fmt: skip
        """A checkpoint of everything sent so far; (updates, online transitions)."""
        updates, online = self._child.call("save", model_paths, replay_path, timeout_s=timeout_s)
        return int(updates), int(online)

    def close(self) -> None:
        """Stop it (asked, then killed) and release the weights. Idempotent."""
        self._child.stop()
        if not self._closed:
            self._closed = True
            self._weights.close()


def main() -> None:
    """The learner process's entry point (``deploy.child.run_child``)."""
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")
    child.run_child(_serve)


if __name__ == "__main__":
    main()
