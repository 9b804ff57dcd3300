"""The pixel feature extractors: keypoints land where the features are, and presets reach SB3."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from sim2real.errors import UnknownNameError
from sim2real.train import RunDir, resolve_config
from sim2real.train.extractors import KeypointCNN, _coords, get_extractor, soft_argmax

Train = Callable[..., Path]


def test_soft_argmax_finds_the_peak_of_each_channel() -> None:
    h, w = 12, 12
    coords = _coords(h, w).reshape(2, -1)
    fmap = th.zeros(1, 2, h, w)
    fmap[0, 0, 3, 9] = 50.0  # row 3, column 9
    fmap[0, 1, 10, 1] = 50.0
    xy = soft_argmax(fmap.flatten(2), coords, th.tensor(1.0)).reshape(2, 2)
    step = 2.0 / (w - 1)
    np.testing.assert_allclose(xy[0].numpy(), [-1 + 9 * step, -1 + 3 * step], atol=1e-4)
    np.testing.assert_allclose(xy[1].numpy(), [-1 + 1 * step, -1 + 10 * step], atol=1e-4)
    # A hot softmax spreads attention: the estimate moves toward the centre of the image.
    soft = soft_argmax(fmap.flatten(2), coords, th.tensor(1e3)).reshape(2, 2)
    assert th.all(soft.abs() < xy.abs())


def test_keypoint_cnn_maps_a_48px_image_to_its_features() -> None:
    space = gym.spaces.Box(0, 255, (3, 48, 48), dtype=np.uint8)
    net = KeypointCNN(space, features_dim=64)
    out = net(th.rand(5, 3, 48, 48))
    assert out.shape == (5, 64) and th.isfinite(out).all()
    out.sum().backward()
    assert net.log_temperature.grad is not None  # the temperature learns too
    with pytest.raises(Exception, match="16x16"):
        KeypointCNN(gym.spaces.Box(0, 255, (3, 8, 8), dtype=np.uint8))


def test_unknown_extractor_names_the_value_and_the_valid_ones(run_dir: Path) -> None:
    with pytest.raises(UnknownNameError, match="'resnet'.*keypoint_cnn, nature_cnn"):
        get_extractor("resnet")
    with pytest.raises(UnknownNameError, match="resnet"):
        resolve_config(
            "kuka-fast", "ppo", run_dir, overrides=["policy_kwargs.features_extractor=resnet"]
        )


def test_preset_extractor_reaches_the_policy_and_reloads(run_dir: Path, tiny: Train) -> None:
    from stable_baselines3 import PPO

    tiny(
        "ppo",
        run_dir,
        env="kuka-fast",
        steps=128,
        extra=["policy_kwargs.features_extractor=keypoint_cnn"],
    )
    model = PPO.load(RunDir(run_dir).model_path, device="cpu")
    assert isinstance(model.policy.features_extractor, KeypointCNN)


def test_a_named_optimizer_reaches_sb3_and_the_tf_style_rmsprop_starts_small() -> None:
    from stable_baselines3.common.sb2_compat.rmsprop_tf_like import RMSpropTFLike

    from sim2real.train.extractors import resolve_policy_kwargs

    out = resolve_policy_kwargs({"optimizer": "rmsprop_tf_like", "optimizer_kwargs": {"eps": 1e-5}})
    assert out["optimizer_class"] is RMSpropTFLike and "optimizer" not in out
    with pytest.raises(UnknownNameError, match="unknown optimizer 'lbfgs'; valid: adam, rmsprop"):
        resolve_policy_kwargs({"optimizer": "lbfgs"})
    # Why the A2C preset names it: PyTorch's RMSprop starts its squared-gradient average at 0, so
    # the first step moves each weight by ~10x the learning rate; the TF-style one by ~lr * |g|.
    steps = {}
    for name, cls in (("torch", th.optim.RMSprop), ("tf", RMSpropTFLike)):
        w = th.nn.Parameter(th.zeros(4))
        opt = cls([w], lr=1e-3, alpha=0.99, eps=1e-5)
        w.grad = th.full((4,), 0.01)
        opt.step()
        steps[name] = float(w.detach().abs().max())
    assert steps["torch"] == pytest.approx(1e-2, rel=1e-2)
    assert steps["tf"] < 1e-4
