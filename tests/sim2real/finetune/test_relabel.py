"""Hindsight goal relabelling on the real reach env's transitions (MuJoCo, DR ``none`` so the
tool estimate is the truth the env's reward is computed from)."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from hardware.spec import ArmSpec
from sim2real.errors import ConfigError
from sim2real.finetune.actor import ObsNormalizer
from sim2real.finetune.learner import Learner, LearnerConfig, RewardShaper
from sim2real.finetune.relabel import EpisodeIndex, Relabeler, default_ratio, goal_fields
from sim2real.policies import shipped


def _source() -> tuple[str, dict[str, Any]]:
    ckpt = shipped()["reach-ddpg"].checkpoint
    assert ckpt is not None
    return str(ckpt[0]), json.loads(ckpt[1].read_text())


def _episodes(spec: ArmSpec, n: int, steps: int) -> list[list[tuple[Any, ...]]]:
    """(obs, action, shaped reward, next_obs) per step, raw, from the env itself."""
    import sim2real.envs as envs

    _, stats = _source()
    config = stats["config"]
    env = envs.make(str(config["env_id"]), spec=spec, dr="none", **config["env_kwargs"])
    shaper = RewardShaper(Learner.action_rate_penalty(config))
    rng = np.random.default_rng(3)
    out = []
    try:
        for ep in range(n):
            obs, _ = env.reset(seed=ep)
            shaper.reset()
            rows = []
            for _ in range(steps):
                a = rng.uniform(-1, 1, 3).astype(np.float32)
                nxt, r, *_ = env.step(a)
                rows.append((obs, a, shaper(float(r), a), nxt))
                obs = nxt
            out.append(rows)
    finally:
        env.close()
    return out


def _relabeler(ratio: float = 1.0) -> tuple[Relabeler, ObsNormalizer]:
    _, stats = _source()
    norm = ObsNormalizer.from_stats(stats["vecnormalize"])
    assert norm is not None
    config = stats["config"]
    relabeler = Relabeler(
        goal_fields(config), ratio, norm.mean, np.sqrt(norm.var + norm.epsilon),
        Learner.action_rate_penalty(config),
    )  # fmt: skip
    return relabeler, norm


def test_relabelling_with_the_episodes_own_goal_gives_back_the_envs_reward(spec: ArmSpec) -> None:
    """Relabelled with the goal it had, a transition is what the env gave: same observation
    (through the normaliser and back), and the env's reward with the training penalty."""
    relabeler, norm = _relabeler()
    f = relabeler.fields
    rows = _episodes(spec, 2, 12)
    obs = np.stack([norm(o) for ep in rows for o, *_ in ep])
    nxt = np.stack([norm(x) for ep in rows for *_, x in ep])
    actions = np.stack([a for ep in rows for _, a, _, _ in ep])
    rewards = np.array([r for ep in rows for _, _, r, _ in ep])
    own_raw = np.stack([x.copy() for ep in rows for *_, x in ep])
    own_raw[:, f.achieved] = own_raw[:, f.goal]  # a "future" that achieved each row's own goal
    own = np.stack([norm(x) for x in own_raw])
    o, n = obs.copy(), nxt.copy()
    got = relabeler.relabel(o, n, actions, own)
    np.testing.assert_allclose(o, obs, atol=2e-5)
    np.testing.assert_allclose(n, nxt, atol=2e-5)
    np.testing.assert_allclose(got, rewards, atol=1e-4)
    assert (rewards < -0.05).all()  # random actions: none of these steps succeeded


def test_a_goal_reached_later_is_a_success_with_consistent_goal_fields(spec: ArmSpec) -> None:
    relabeler, norm = _relabeler()
    f = relabeler.fields
    (episode,) = _episodes(spec, 1, 10)
    obs = np.stack([norm(o) for o, *_ in episode])
    nxt = np.stack([norm(x) for *_, x in episode])
    actions = np.stack([a for _, a, _, _ in episode])
    last = np.repeat(nxt[-1:], len(obs), axis=0)
    rewards = relabeler.relabel(obs, nxt, actions, last)
    raw = lambda x: x * np.sqrt(norm.var + norm.epsilon) + norm.mean  # noqa: E731
    reached = raw(last)[:, f.achieved]
    for x in (raw(obs), raw(nxt)):
        np.testing.assert_allclose(x[:, f.goal], reached, atol=1e-5)
        for field, ref in f.deltas:
            np.testing.assert_allclose(x[:, field], reached - x[:, ref], atol=1e-5)
    penalty = 0.5 * np.sum((actions - raw(obs)[:, f.prev_action]) ** 2, axis=1)
    assert rewards[-1] == pytest.approx(1.0 - penalty[-1], abs=1e-4)  # reached: the bonus
    d = np.linalg.norm(raw(nxt)[:-1, f.achieved] - reached[:-1], axis=1)
    np.testing.assert_allclose(rewards[:-1], -5.0 * d + (d < 0.01) - penalty[:-1], atol=1e-4)


def test_episode_index_finds_episodes_from_the_observations_and_forgets_overwritten_rows(
    spec: ArmSpec,
) -> None:
    episodes = _episodes(spec, 3, 5)
    index = EpisodeIndex(capacity=12)
    flat = [(o, x) for ep in episodes for o, _, _, x in ep]
    for row, (o, x) in enumerate(flat[:12]):
        index.add(row, o, x)
    np.testing.assert_array_equal(index.episode, [0] * 5 + [1] * 5 + [2] * 2)
    rng = np.random.default_rng(0)
    for _ in range(20):
        fut = index.future(np.array([0, 4, 6, 11]), rng)
        assert 0 <= fut[0] <= 4 and fut[1] == 4 and 6 <= fut[2] <= 9 and fut[3] == 11
    for k, (o, x) in enumerate(flat[12:15]):  # the buffer wraps over episode 0
        index.add(k, o, x)
    np.testing.assert_array_equal(index.episode[:3], [2, 2, 2])
    for _ in range(20):
        fut = index.future(np.array([10, 3]), rng)
        assert fut[0] in (10, 11, 0, 1, 2)  # episode 2 runs over the wrap
        assert 3 <= fut[1] <= 4  # episode 0's surviving rows


def test_the_learner_relabels_its_share_of_online_rows_and_reloads_its_episodes(
    spec: ArmSpec, tmp_path: Any
) -> None:
    zip_path, stats = _source()
    config = stats["config"]
    cfg = LearnerConfig(
        algo="ddpg", source_algo="ddpg", model_zip=zip_path, obs_stats=stats["vecnormalize"],
        relabel_ratio=0.5,
        goal_fields=goal_fields(config), action_rate_penalty=Learner.action_rate_penalty(config),
    )  # fmt: skip
    learner = Learner(cfg)
    norm = learner.normalizer
    assert norm is not None
    for episode in _episodes(spec, 4, 10):
        for o, a, r, x in episode:
            learner.add(norm(o), a, r, norm(x), False)
    buf = learner.buffer
    assert buf.episodes is not None
    np.testing.assert_array_equal(buf.episodes.episode[:40], np.repeat(np.arange(4), 10))
    batch = buf.sample(400)
    obs = batch.observations.numpy()
    stored = {o.tobytes() for o in buf.observations[:40, 0]}
    changed = np.array([o.tobytes() not in stored for o in obs])
    assert 0.3 < changed.mean() < 0.6  # half relabelled, a few onto their own goal
    learner.train(4)  # SB3's update runs on relabelled batches
    learner.save([str(tmp_path / "m.zip")], str(tmp_path / "r.npz"))
    again = Learner(
        LearnerConfig(**{**cfg.__dict__, "replay_npz": str(tmp_path / "r.npz")})
    )  # fmt: skip
    assert again.buffer.episodes is not None
    np.testing.assert_array_equal(again.buffer.episodes.episode[:40], np.repeat(np.arange(4), 10))


def test_tasks_without_goal_fields_are_named() -> None:
    _, stats = _source()
    pick = {**stats["config"], "task": "pick"}
    assert default_ratio(pick) == 0.0 and default_ratio(stats["config"]) > 0
    with pytest.raises(ConfigError, match="'pick'"):
        goal_fields(pick)
    with pytest.raises(ConfigError, match="1.5"):
        _relabeler(1.5)
