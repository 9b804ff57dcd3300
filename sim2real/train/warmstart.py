"""Start an off-policy run from a policy that already solves the task (a teacher).

Why: a policy that ``finetune`` can train on the arm needs a critic (DDPG, TD3), but on this
2-core CPU an off-policy learner is bound by its gradient updates (~150 env steps/s against PPO's
~1,000), so pick, which PPO learns in ~3 M env steps, is out of its reach from scratch in an hour.
The teacher's experience closes most of that gap before the first update (as in DDPGfD, Večerík
et al. 2017, and Jump-Start RL, Uchendu et al. 2023). Three stages, before SB3's ``learn``:

1. **Collect**: the teacher acts in the run's own training envs (DR, start curriculum and the
   safety filter included), its deterministic action plus Gaussian exploration noise, for
   ``transitions`` env steps. Each transition goes into the replay buffer as the learner's own
   would (original observations and rewards, the terminal observation at an episode's end, a
   time limit not taken for a termination), and counts against the run's step budget.
2. **Clone**: the actor (and its target) regresses to the teacher's noiseless actions on those
   observations, normalised by the run's ``VecNormalize`` (whose statistics they made).
3. **Evaluate**: ``critic_updates`` critic updates of the algorithm's own target (TD3's clipped
   double Q with target smoothing; DDPG's single Q) with the cloned actor held fixed, so the
   first policy updates climb a critic that has learned the teacher's returns, not a random one.

Then SB3 learns as usual from a full buffer. The teacher is anything ``load_policy`` opens (a run
directory, an exported file, a shipped name) with the same observation layout and actions.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.utils import polyak_update
from torch.nn import functional

from sim2real.errors import ConfigError
from sim2real.runmeta import RunMeta

WARM_START_KEYS: tuple[str, ...] = (
    "teacher",
    "transitions",
    "noise_sigma",
    "bc_epochs",
    "bc_batch_size",
    "critic_updates",
)


@dataclass(frozen=True)
class WarmStart:
    """The preset's ``warm_start`` mapping, validated."""

    teacher: str
    transitions: int = 50_000  # env steps the teacher collects (all envs together)
    noise_sigma: float = 0.1  # exploration noise on the teacher's actions, normalised units
    bc_epochs: int = 20
    bc_batch_size: int = 256
    critic_updates: int = 20_000

    def __post_init__(self) -> None:
        if not isinstance(self.teacher, str) or not self.teacher:
            raise ConfigError(f"warm_start.teacher must name a policy, got {self.teacher!r}")
        for name in ("transitions", "bc_batch_size"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ConfigError(f"warm_start.{name} must be an integer >= 1, got {v!r}")
        for name in ("bc_epochs", "critic_updates"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 0:
                raise ConfigError(f"warm_start.{name} must be an integer >= 0, got {v!r}")
        s = self.noise_sigma
        if not isinstance(s, int | float) or isinstance(s, bool) or not 0 <= s <= 1:
            raise ConfigError(f"warm_start.noise_sigma must be in [0, 1], got {s!r}")

    @classmethod
    def from_mapping(cls, data: Any) -> WarmStart:
        if not isinstance(data, Mapping):
            raise ConfigError(
                f"warm_start must be a mapping like {{teacher: pick-ppo}}, got {data!r}"
            )
        unknown = sorted(set(data) - set(WARM_START_KEYS))
        if unknown:
            raise ConfigError(
                f"warm_start: unknown key(s) {unknown}; valid: {sorted(WARM_START_KEYS)}"
            )
        if "teacher" not in data:
            raise ConfigError("warm_start needs a teacher (a run dir or a shipped policy name)")
        return cls(**dict(data))


def _td3_critic_update(model: Any, batch_size: int, k: int) -> float:
    """Update ``k`` of TD3's (or DDPG's: no smoothing, one Q) critic on its own target, the
    actor fixed: SB3's ``TD3.train`` without the actor step (n-step discounts where the buffer
    has them; the critic target follows every ``policy_delay`` updates, as there)."""
    data = model.replay_buffer.sample(batch_size, env=model._vec_normalize_env)
    discounts = data.discounts if data.discounts is not None else model.gamma
    with th.no_grad():
        noise = data.actions.clone().data.normal_(0, model.target_policy_noise)
        noise = noise.clamp(-model.target_noise_clip, model.target_noise_clip)
        next_actions = (model.actor_target(data.next_observations) + noise).clamp(-1, 1)
        next_q = th.cat(model.critic_target(data.next_observations, next_actions), dim=1)
        next_q, _ = th.min(next_q, dim=1, keepdim=True)
        target_q = data.rewards + (1 - data.dones) * discounts * next_q
    current = model.critic(data.observations, data.actions)
    loss = sum(functional.mse_loss(q, target_q) for q in current)
    assert isinstance(loss, th.Tensor)
    model.critic.optimizer.zero_grad()
    loss.backward()
    model.critic.optimizer.step()
    if (k + 1) % model.policy_delay == 0:
        polyak_update(model.critic.parameters(), model.critic_target.parameters(), model.tau)
        polyak_update(model.critic_batch_norm_stats, model.critic_batch_norm_stats_target, 1.0)
    return float(loss.item())


# algo -> critic-only update k on a replay batch (returns the loss)
CRITIC_UPDATES: dict[str, Callable[[Any, int, int], float]] = {
    "td3": _td3_critic_update,
    "ddpg": _td3_critic_update,
}


def check_algo(algo: str) -> None:
    if algo not in CRITIC_UPDATES:
        raise ConfigError(
            f"warm_start works with {sorted(CRITIC_UPDATES)} (an actor and a Q critic), "
            f"not {algo!r}"
        )


def check_teacher(
    name: str, teacher: RunMeta, env_id: str, layout: tuple[Any, ...], action_dim: int
) -> None:
    """The teacher reads the student's observation and writes its actions, field by field."""
    mine = [(f.name, f.start, f.stop) for f in layout]
    theirs = [(f.name, f.start, f.stop) for f in teacher.obs_layout]
    if theirs != mine or teacher.action_dim != action_dim:
        raise ConfigError(
            f"warm_start teacher {name!r} ({teacher.env_id}) does not read this run's "
            f"observation ({env_id}): its layout is {[n for n, *_ in theirs]}, this run's "
            f"{[n for n, *_ in mine]}"
        )


def warm_start(
    model: Any,
    algo: str,
    ws: WarmStart,
    teacher: Callable[[np.ndarray], np.ndarray],
    seed: int,
) -> dict[str, Any]:
    """The three stages on a new off-policy ``model`` of ``algo``; returns their figures."""
    check_algo(algo)
    update = CRITIC_UPDATES[algo]
    venv, vn = model.get_env(), model.get_vec_normalize_env()
    n_envs = venv.num_envs
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()

    # 1. collect
    obs = venv.reset()
    raw = vn.get_original_obs() if vn is not None else obs
    seen: list[np.ndarray] = []
    taught: list[np.ndarray] = []
    episodes = successes = 0
    for _ in range(-(-ws.transitions // n_envs)):
        clean = np.clip(np.asarray(teacher(raw.astype(np.float32)), dtype=np.float32), -1, 1)
        noisy = clean + ws.noise_sigma * rng.standard_normal(clean.shape).astype(np.float32)
        action = np.clip(noisy, -1.0, 1.0)
        new_obs, rewards, dones, infos = venv.step(action)
        new_raw = vn.get_original_obs() if vn is not None else new_obs
        raw_rewards = vn.get_original_reward() if vn is not None else rewards
        next_raw = np.array(new_raw, copy=True)
        for i, done in enumerate(dones):
            if done and infos[i].get("terminal_observation") is not None:
                term = infos[i]["terminal_observation"]
                next_raw[i] = vn.unnormalize_obs(term) if vn is not None else term
                episodes += 1
                successes += int(bool(infos[i].get("is_success", False)))
        model.replay_buffer.add(
            raw, next_raw, model.policy.scale_action(action), raw_rewards, dones, infos
        )
        seen.append(np.array(raw, copy=True))
        taught.append(clean)
        raw = new_raw
    collected = len(seen) * n_envs
    model.num_timesteps += collected  # they are env steps of this run
    collect_s = time.perf_counter() - t0

    # 2. clone
    t1 = time.perf_counter()
    x_raw = np.concatenate(seen)
    x = vn.normalize_obs(x_raw) if vn is not None else x_raw
    obs_t = th.as_tensor(np.asarray(x, dtype=np.float32))
    act_t = th.as_tensor(np.concatenate(taught))
    actor = model.actor
    with th.no_grad():
        bc_initial = float(functional.mse_loss(actor(obs_t), act_t).item())
    bc_loss = bc_initial
    gen = th.Generator().manual_seed(seed)
    for _ in range(ws.bc_epochs):
        order = th.randperm(len(obs_t), generator=gen)
        total = 0.0
        for start in range(0, len(order), ws.bc_batch_size):
            idx = order[start : start + ws.bc_batch_size]
            loss = functional.mse_loss(actor(obs_t[idx]), act_t[idx])
            actor.optimizer.zero_grad()
            loss.backward()
            actor.optimizer.step()
            total += float(loss.item()) * len(idx)
        bc_loss = total / len(order)
    model.actor_target.load_state_dict(actor.state_dict())
    clone_s = time.perf_counter() - t1

    # 3. evaluate the cloned actor
    t2 = time.perf_counter()
    batch = int(model.batch_size)
    critic_losses = [update(model, batch, k) for k in range(ws.critic_updates)]
    tenth = max(len(critic_losses) // 10, 1)
    head, tail = critic_losses[:tenth], critic_losses[-tenth:]
    venv.reset()  # learn() starts its episodes afresh
    return {
        "teacher": ws.teacher,
        "transitions": collected,
        "teacher_episodes": episodes,
        "teacher_success_rate": successes / episodes if episodes else None,
        "bc_epochs": ws.bc_epochs,
        "bc_initial_mse": bc_initial,
        "bc_final_mse": bc_loss,
        "critic_updates": ws.critic_updates,
        # mean loss over the first and the last tenth of the updates
        "critic_initial_loss": float(np.mean(head)) if head else None,
        "critic_final_loss": float(np.mean(tail)) if tail else None,
        "collect_s": round(collect_s, 2),
        "clone_s": round(clone_s, 2),
        "critic_s": round(time.perf_counter() - t2, 2),
    }
