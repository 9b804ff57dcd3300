"""The loop's numpy actor against SB3's own, and the learner's model and buffers, in-process."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from hardware.spec import ArmSpec
from sim2real.finetune.actor import NumpyActor, ObsNormalizer, actor_arrays, flatten
from sim2real.finetune.learner import Learner, LearnerConfig, SimBufferConfig
from sim2real.policies import shipped


def _ddpg_source() -> tuple[Path, dict[str, object]]:
    import json

    ckpt = shipped()["reach-ddpg"].checkpoint
    assert ckpt is not None
    stats = json.loads(ckpt[1].read_text())
    return ckpt[0], stats


def _reach_ddpg_config(**kw: Any) -> LearnerConfig:
    """A learner on the shipped ``reach-ddpg`` (24 observations, 3 actions)."""
    zip_path, stats = _ddpg_source()
    base: dict[str, Any] = {
        "algo": "ddpg", "source_algo": "ddpg", "model_zip": str(zip_path),
        "obs_stats": stats["vecnormalize"],
    }  # fmt: skip
    return LearnerConfig(**{**base, **kw})


def test_numpy_actor_matches_the_sb3_ddpg_actor_with_frozen_normalisation() -> None:
    from sim2real.train.algos import get_algo

    zip_path, stats = _ddpg_source()
    model = get_algo("ddpg").cls.load(  # type: ignore[attr-defined]
        str(zip_path), device="cpu", custom_objects={"buffer_size": 1}
    )
    kind, arrays = actor_arrays(model)
    norm = ObsNormalizer.from_stats(stats["vecnormalize"])  # type: ignore[arg-type]
    assert kind == "deterministic" and norm is not None
    actor = NumpyActor(kind, [a.shape for a in arrays], flatten(arrays), norm)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(32, 24)).astype(np.float32) * 0.2
    with th.no_grad():
        want = model.policy.actor(th.as_tensor(np.stack([norm(o) for o in obs]))).numpy()
    got = np.stack([actor.act(o) for o in obs])
    assert np.allclose(got, want, atol=1e-5)
    noisy = actor.explore(obs[0], rng)
    assert noisy.shape == (3,) and np.all(np.abs(noisy) <= 1) and not np.allclose(noisy, got[0])


def test_numpy_actor_matches_a_sac_actor() -> None:
    from stable_baselines3 import SAC

    env = gym.make("Pendulum-v1")
    model = SAC("MlpPolicy", env, policy_kwargs={"net_arch": [16, 8]}, device="cpu", seed=0)
    kind, arrays = actor_arrays(model)
    actor = NumpyActor(kind, [a.shape for a in arrays], flatten(arrays), None)
    obs = np.random.default_rng(1).normal(size=(16, 3)).astype(np.float32)
    with th.no_grad():
        want = model.policy.actor(th.as_tensor(obs), deterministic=True).numpy()
    assert kind == "gaussian"
    assert np.allclose(np.stack([actor.act(o) for o in obs]), want, atol=1e-5)
    env.close()


def test_td3_continues_a_ddpg_checkpoint_and_batches_mix_sim_and_online_half_half(
    spec: ArmSpec,
) -> None:
    zip_path, stats = _ddpg_source()
    config = stats["config"]
    assert isinstance(config, dict)
    cfg = LearnerConfig(
        algo="td3",
        source_algo="ddpg",
        model_zip=str(zip_path),
        obs_stats=stats["vecnormalize"],  # type: ignore[arg-type]
        learning_starts=10,
        batch_size=16,
        sim_buffer=SimBufferConfig(
            env_id=str(config["env_id"]),
            env_kwargs=dict(config.get("env_kwargs", {})),
            spec=spec,
            steps=120,
        ),
    )
    learner = Learner(cfg)
    assert learner.model.policy_delay == 2 and learner.model.target_policy_noise > 0
    assert learner.buffer.sim is not None and learner.buffer.sim.size() == 120
    before = learner.flat_actor()
    rng = np.random.default_rng(2)
    for _ in range(
        40
    ):  # online rewards far from any sim reward: the batch says where rows came from
        obs, nxt = rng.normal(size=24).astype(np.float32), rng.normal(size=24).astype(np.float32)
        learner.add(obs, rng.uniform(-1, 1, 3).astype(np.float32), 1000.0, nxt, False)
    batch = learner.buffer.sample(16)
    online = int((batch.rewards.numpy() == 1000.0).sum())
    assert online == 8 and len(batch.rewards) == 16
    learner.train(4)
    assert learner.updates > 0
    assert not np.allclose(learner.flat_actor(), before)


@pytest.mark.parametrize("bad", [{"norm_obs": False}, None])
def test_no_normaliser_without_normalised_observations(bad: dict[str, object] | None) -> None:
    assert ObsNormalizer.from_stats(bad) is None


def test_critic_warm_up_trains_the_critic_and_leaves_the_actor_until_actor_starts() -> None:
    zip_path, stats = _ddpg_source()
    cfg = LearnerConfig(
        algo="ddpg",
        source_algo="ddpg",
        model_zip=str(zip_path),
        obs_stats=stats["vecnormalize"],  # type: ignore[arg-type]
        batch_size=16,
        actor_starts=60,
    )
    learner = Learner(cfg)
    model = learner.model
    actor0 = learner.flat_actor()
    actor_target0 = flatten([p.detach().numpy().copy() for p in model.actor_target.parameters()])
    critic0 = flatten([p.detach().numpy().copy() for p in model.critic.parameters()])
    target0 = flatten([p.detach().numpy().copy() for p in model.critic_target.parameters()])
    rng = np.random.default_rng(3)

    def add(n: int) -> None:
        for _ in range(n):
            obs, nxt = rng.normal(size=(2, 24)).astype(np.float32)
            learner.add(obs, rng.uniform(-1, 1, 3).astype(np.float32), -5.0, nxt, False)

    add(40)
    learner.train(5)
    assert learner.updates - learner.start_updates == 5
    assert np.array_equal(learner.flat_actor(), actor0)  # the actor waits for the critic
    after = [p.detach().numpy() for p in model.actor_target.parameters()]
    assert np.array_equal(flatten(after), actor_target0)
    assert not np.allclose(
        flatten([p.detach().numpy() for p in model.critic.parameters()]), critic0
    )
    assert not np.allclose(
        flatten([p.detach().numpy() for p in model.critic_target.parameters()]), target0
    )  # its target follows (Polyak)
    assert model.policy_delay == learner.policy_delay
    add(20)  # 60 online transitions: the actor learns from here on
    learner.train(2)
    assert not np.allclose(learner.flat_actor(), actor0)


def test_reward_shaper_gives_the_training_wrappers_rewards(spec: ArmSpec) -> None:
    """The online reward is the one the critic learned: the env's reward with the source run's
    action-rate penalty, step for step the same as ``ActionRatePenalty`` over the same env."""
    import sim2real.envs as envs
    from sim2real.finetune.learner import RewardShaper
    from sim2real.train.wrappers import ActionRatePenalty

    _, stats = _ddpg_source()
    config = stats["config"]
    assert isinstance(config, dict)
    coef = Learner.action_rate_penalty(config)
    assert coef == 0.5  # reach-ddpg was trained with it
    kwargs = dict(config.get("env_kwargs", {}))
    plain = envs.make(str(config["env_id"]), spec=spec, **kwargs)
    wrapped = ActionRatePenalty(envs.make(str(config["env_id"]), spec=spec, **kwargs), coef)
    shaper = RewardShaper(coef)
    rng = np.random.default_rng(4)
    for episode in range(2):
        plain.reset(seed=episode)
        wrapped.reset(seed=episode)
        shaper.reset()
        for _ in range(8):
            a = rng.uniform(-1, 1, 3).astype(np.float32)
            _, r, *_ = plain.step(a)
            _, want, *_ = wrapped.step(a)
            assert shaper(r, a) == pytest.approx(want, abs=1e-12)
            assert want < r  # the penalty is there
    plain.close()
    wrapped.close()
    with pytest.raises(Exception, match="-1"):
        RewardShaper(-1.0)


def _pick_ddpg_source() -> tuple[Path, dict[str, object]]:
    import json

    ckpt = shipped()["pick-ddpg"].checkpoint
    assert ckpt is not None
    return ckpt[0], json.loads(ckpt[1].read_text())


def test_the_source_anchor_keeps_the_actor_near_the_source_under_updates_that_pull_it_away() -> (
    None
):
    """A DAgger-trained source keeps its anchor on the arm: the same transitions (a reward that
    pays for one action component's low end, whatever the state) move an
    anchored actor's actions less from the source's than an unanchored one's (a fifth less at
    least; the source's own learning rate, updates in chunks as the learner process runs them)."""
    from sim2real.finetune.checkpoint import resolve
    from sim2real.finetune.runner import DAGGER_ANCHOR_RATIO, default_anchor

    zip_path, stats = _pick_ddpg_source()
    assert default_anchor(resolve("pick-ddpg", None).config) == DAGGER_ANCHOR_RATIO
    assert default_anchor(resolve("reach-ddpg", None).config) == 0.0
    drift = {}
    for ratio in (0.0, 2.0):
        cfg = LearnerConfig(
            algo="ddpg", source_algo="ddpg", model_zip=str(zip_path),
            obs_stats=stats["vecnormalize"],  # type: ignore[arg-type]
            batch_size=32, anchor_ratio=ratio, anchor_zip=str(zip_path) if ratio else None,
        )  # fmt: skip
        learner = Learner(cfg)
        n_obs = learner.model.observation_space.shape[0]
        probe = np.random.default_rng(0).normal(size=(64, n_obs)).astype(np.float32)
        with th.no_grad():
            before = learner.model.actor(th.as_tensor(probe)).numpy()
        rng = np.random.default_rng(5)
        for _ in range(200):
            obs, nxt = rng.normal(size=(2, n_obs)).astype(np.float32)
            action = rng.uniform(-1, 1, 4).astype(np.float32)
            learner.add(obs, action, float(-action[3]), nxt, False)  # pays a closed gripper
        for _ in range(50):  # in chunks, as the learner process trains between transitions
            learner.train(2)
        with th.no_grad():
            after = learner.model.actor(th.as_tensor(probe)).numpy()
        drift[ratio] = float(np.mean(np.abs(after - before)))
        assert learner.imitation_updates == int(ratio * 100)
    assert drift[2.0] < 0.8 * drift[0.0], drift


@pytest.mark.parametrize("bad", [-0.5, float("nan")])
def test_an_anchor_ratio_that_is_not_a_count_is_refused(bad: float) -> None:
    from sim2real.finetune.learner import LearnerError

    with pytest.raises(LearnerError, match="anchor ratio"):
        LearnerConfig(algo="ddpg", source_algo="ddpg", model_zip="m.zip", obs_stats=None,
                      anchor_ratio=bad, anchor_zip="m.zip")  # fmt: skip


def test_success_imitation_learns_only_from_successful_episodes_and_resumes_with_them(
    tmp_path: Path,
) -> None:
    """``actor_update="success"``: the actor regresses on the actions of episodes that ended in
    success, never on a failed one's; the critic learns meanwhile; a checkpoint carries which
    rows were successful, so a resumed run goes on imitating them."""
    from dataclasses import replace

    cfg = _reach_ddpg_config(batch_size=32, actor_update="success", imitation_ratio=2.0)
    rng = np.random.default_rng(6)
    good, bad = rng.normal(size=(2, 40, 24)).astype(np.float32)

    def episode(learner: Learner, states: np.ndarray, action: float, success: bool) -> None:
        for o in states:
            learner.add(o, np.full(3, action, np.float32), 1.0 if success else -1.0, o, False)
        learner.end_episode(success)

    def act(learner: Learner, states: np.ndarray) -> np.ndarray:
        with th.no_grad():
            return learner.model.actor(th.as_tensor(states)).numpy()

    # a failed episode alone teaches the actor nothing
    failed = Learner(cfg)
    episode(failed, bad, -0.9, False)
    actor0 = failed.flat_actor()
    critic0 = flatten([p.detach().numpy().copy() for p in failed.model.critic.parameters()])
    failed.train(10)
    assert failed.successful_transitions == 0 and failed.own_imitation_updates == 0
    assert np.array_equal(failed.flat_actor(), actor0)
    critic = flatten([p.detach().numpy() for p in failed.model.critic.parameters()])
    assert not np.allclose(critic, critic0)  # the critic learns all the same

    learner = Learner(cfg)
    episode(learner, good, 0.9, True)
    episode(learner, bad, -0.9, False)
    assert learner.successful_transitions == len(good)
    before = np.abs(act(learner, good) - 0.9).mean()
    for _ in range(20):
        learner.train(2)
    assert learner.own_imitation_updates == 80
    after = np.abs(act(learner, good) - 0.9).mean()
    assert after < 0.5 * before, (before, after)
    model_zip, replay = tmp_path / "m.zip", tmp_path / "r.npz"
    learner.save([str(model_zip)], str(replay))
    resumed = Learner(replace(cfg, model_zip=str(model_zip), replay_npz=str(replay), resume=True))
    assert resumed.successful_transitions == len(good)
    assert resumed.buffer.size() == len(good) + len(bad)


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [("actor_update", "qfilter", "'qfilter'"), ("imitation_ratio", 0.0, "imitation ratio 0.0")],
)
def test_an_unknown_actor_update_or_a_bad_imitation_ratio_is_refused(
    field: str, value: object, match: str
) -> None:
    from sim2real.finetune.learner import LearnerError

    with pytest.raises(LearnerError, match=match):
        LearnerConfig(algo="ddpg", source_algo="ddpg", model_zip="m.zip", obs_stats=None,
                      **{field: value})  # type: ignore[arg-type]  # fmt: skip


def test_advantage_weighted_imitation_follows_the_better_of_the_actions_taken() -> None:
    """``actor_update="advantage"``: two actions taken on the same states, one paid and one
    fined; once the critic has learned that, the actor moves towards the paid one (plain
    imitation of both would sit between them)."""
    learner = Learner(
        _reach_ddpg_config(batch_size=64, actor_update="advantage", imitation_ratio=1.0)
    )
    rng = np.random.default_rng(7)
    states = rng.normal(size=(64, 24)).astype(np.float32)
    paid, fined = np.full(3, 0.8, np.float32), np.full(3, -0.8, np.float32)
    for o in states:
        learner.add(o, paid, 1.0, o, True)
        learner.add(o, fined, -1.0, o, True)
    learner.end_episode(False)
    with th.no_grad():
        before = learner.model.actor(th.as_tensor(states)).numpy()
    for _ in range(100):  # the critic learns what each action earns as the actor follows it
        learner.train(4)
    with th.no_grad():
        after = learner.model.actor(th.as_tensor(states)).numpy()
    assert learner.own_imitation_updates == 400
    assert np.abs(after - paid).mean() < 0.5 * np.abs(before - paid).mean()
    assert after.mean() > 0.3, after.mean()


def test_correlated_exploration_noise_has_its_std_and_correlation_and_a_gripper_std_of_its_own(
) -> None:  # fmt: skip
    """AR(1) noise: unit-variance steps scaled per component (the gripper, last, by its own
    std), correlated ``exp(-1 / corr_steps)`` from one step to the next; white noise is not."""
    zip_path, _ = _ddpg_source()
    from sim2real.train.algos import get_algo

    model = get_algo("ddpg").cls.load(  # type: ignore[attr-defined]
        str(zip_path), device="cpu", custom_objects={"buffer_size": 1}
    )
    kind, arrays = actor_arrays(model)
    shapes = [a.shape for a in arrays]
    # small stds: the clip to [-1, 1] leaves the noise whole
    obs = np.zeros(24, np.float32)
    lag1 = {}
    for corr in (0.0, 10.0):
        actor = NumpyActor(kind, shapes, flatten(arrays), None, 0.02, corr, 0.05)
        rng = np.random.default_rng(8)
        base = actor.act(obs)
        noise = np.stack([actor.explore(obs, rng) - base for _ in range(4000)])
        assert noise[:, :2].std() == pytest.approx(0.02, rel=0.15)
        assert noise[:, 2].std() == pytest.approx(0.05, rel=0.15)  # the last: the "gripper"
        lag1[corr] = float(np.corrcoef(noise[:-1, 0], noise[1:, 0])[0, 1])
    assert abs(lag1[0.0]) < 0.1
    assert lag1[10.0] == pytest.approx(np.exp(-0.1), abs=0.05)
