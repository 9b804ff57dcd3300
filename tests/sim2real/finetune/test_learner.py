"""The loop's numpy actor against SB3's own, and the learner's model and buffers, in-process."""

from __future__ import annotations

from pathlib import Path

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
