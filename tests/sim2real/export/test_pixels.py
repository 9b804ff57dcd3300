"""Pixel actors export: each image op computes what torch does in numpy and in onnxruntime, whole
keypoint and NatureCNN actors (random weights, no training) choose torch's action on every
frame, an actor that reads proprioception beside the frame reads both apart, the discrete action
reaches the Kuka env as an index, and what stays unsupported is refused in one line."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from sim2real.export import FORMATS, PolicyError, PolicyMeta, load_policy
from sim2real.export.exporter import _layers, build_program
from sim2real.export.program import Op
from sim2real.export.torch_policy import TorchPolicy
from sim2real.train.augment import PIXELS_KEY, PRIVILEGED_KEY
from sim2real.train.extractors import _coords, resolve_policy_kwargs, soft_argmax

th.set_num_threads(1)

KUKA = "Sim2Real/KukaGraspFast-v0"
FRAME = (48, 48, 3)  # what the env observes: channels last, uint8
CHW = gym.spaces.Box(0, 255, (3, 48, 48), dtype=np.uint8)  # what SB3's CNN reads
PRIVILEGED = gym.spaces.Box(-np.inf, np.inf, (25,), dtype=np.float32)
SCORE_TOLERANCE = 1e-5


def _meta(obs_shape: tuple[int, ...], action_dim: int, **kw: Any) -> PolicyMeta:
    return PolicyMeta(
        env_id=KUKA,
        algo="distill",
        dr="none",
        spec_name="arm3",
        spec_fingerprint="0" * 16,
        obs_shape=obs_shape,
        action_dim=action_dim,
        obs_mode="pixels",
        **kw,
    )


def _exported(program: list[Op], meta: PolicyMeta, tmp_path: Path) -> dict[str, Any]:
    """The program saved in every format and loaded back (the .npz round trip included)."""
    return {
        name: load_policy(fmt.save(tmp_path / f"p{fmt.suffix}", program, meta))
        for name, fmt in FORMATS.items()
    }


def _frames(n: int, seed: int = 0) -> np.ndarray:
    """Smooth random images with a few bright blobs: soft-argmax peaks, not white noise."""
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 256, (n, 6, 6, 3)).repeat(8, axis=1).repeat(8, axis=2)
    return base.astype(np.uint8)


def _torch_nchw(frames: np.ndarray) -> th.Tensor:
    return th.from_numpy(frames).permute(0, 3, 1, 2).float() / 255.0


# ---- one op at a time ---------------------------------------------------------------------------
def _as_image(shape: tuple[int, int, int]) -> Op:
    """A flat (n, C·H·W) float input as the (n, C, H, W) array an op under test reads."""
    return {"op": "image", "layout": "chw", "shape": list(shape), "divisor": 1.0}


def _check_op(op: Op, x: np.ndarray, expected: th.Tensor, tmp_path: Path) -> None:
    program = [_as_image(x.shape[1:]), op, {"op": "flatten"}]
    want = expected.detach().reshape(len(x), -1).numpy()
    for name, policy in _exported(program, _meta(x.shape[1:], want.shape[1]), tmp_path).items():
        got = policy(x)
        assert got.shape == want.shape and got.dtype == np.float32, name
        np.testing.assert_allclose(got, want, atol=1e-5, rtol=1e-5, err_msg=name)


def test_image_op_is_sb3s_transpose_and_divide_bit_for_bit(tmp_path: Path) -> None:
    frames = np.random.default_rng(1).integers(0, 256, (4, 6, 5, 3)).astype(np.uint8)
    program = [
        {"op": "image", "layout": "hwc", "shape": [3, 6, 5], "divisor": 255.0},
        {"op": "flatten"},
    ]
    want = _torch_nchw(frames).reshape(4, -1).numpy()
    for name, policy in _exported(program, _meta((6, 5, 3), 90), tmp_path).items():
        np.testing.assert_array_equal(policy(frames), want, err_msg=name)


@pytest.mark.parametrize(
    ("kernel", "stride", "padding"),
    [(3, 1, 0), (3, 2, 1), (8, 4, 0), ((3, 2), (2, 1), (1, 0))],
)
def test_conv2d_op_matches_torch(kernel: Any, stride: Any, padding: Any, tmp_path: Path) -> None:
    th.manual_seed(0)
    conv = th.nn.Conv2d(4, 6, kernel, stride=stride, padding=padding)
    (op,) = _layers(conv)
    x = np.random.default_rng(2).normal(size=(5, 4, 17, 13)).astype(np.float32)
    _check_op(op, x, conv(th.from_numpy(x)), tmp_path)


def test_conv2d_op_refuses_what_it_does_not_compute() -> None:
    for conv in (
        th.nn.Conv2d(2, 2, 3, padding="same"),
        th.nn.Conv2d(2, 2, 3, dilation=2),
        th.nn.Conv2d(2, 2, 3, groups=2),
        th.nn.Conv2d(2, 2, 3, padding=1, padding_mode="reflect"),
    ):
        with pytest.raises(PolicyError, match="only integer zero padding"):
            _layers(conv)


def test_coord_concat_op_appends_coordconv_channels(tmp_path: Path) -> None:
    coords = _coords(9, 7)
    x = np.random.default_rng(3).normal(size=(3, 2, 9, 7)).astype(np.float32)
    op = {"op": "coord_concat", "coords": coords.numpy()}
    _check_op(op, x, th.cat((th.from_numpy(x), coords.expand(3, -1, -1, -1)), dim=1), tmp_path)


def test_keypoints_op_is_the_keypoint_cnns_soft_argmax_and_presence(tmp_path: Path) -> None:
    x = (3 * np.random.default_rng(4).normal(size=(6, 5, 12, 10))).astype(np.float32)
    map_coords = _coords(12, 10).reshape(2, -1)
    temperature = th.exp(th.tensor(-0.6))
    fmap = th.from_numpy(x).flatten(2)
    expected = th.cat(
        (soft_argmax(fmap, map_coords, temperature), th.relu(fmap).amax(dim=-1)), dim=1
    )
    op = {
        "op": "keypoints",
        "map_coords": map_coords.numpy(),
        "temperature": temperature.numpy().astype(np.float32),
    }
    _check_op(op, x, expected, tmp_path)


def test_argmax_op_outputs_the_index_and_exposes_its_scores(tmp_path: Path) -> None:
    scores = np.random.default_rng(5).normal(size=(50, 7)).astype(np.float32)
    for name, policy in _exported([{"op": "argmax"}], _meta((7,), 1), tmp_path).items():
        got = policy(scores)
        assert got.shape == (50, 1) and got.dtype == np.float32, name
        np.testing.assert_array_equal(got[:, 0], scores.argmax(axis=1))
        np.testing.assert_array_equal(policy.scores(scores), scores)
        assert policy(scores[0]).shape == (1,) and policy.scores(scores[0]).shape == (7,)


def test_a_continuous_program_has_no_scores(tmp_path: Path) -> None:
    program = [{"op": "act", "fn": "tanh"}]
    for policy in _exported(program, _meta((3,), 3), tmp_path).values():
        assert policy.scores(np.zeros(3, np.float32)) is None


def test_an_unknown_image_layout_is_refused_naming_it(tmp_path: Path) -> None:
    program = [{"op": "image", "layout": "hcw", "shape": [3, 4, 4], "divisor": 255.0}]
    for fmt in FORMATS.values():  # refused when written (ONNX) or read (.npz)
        with pytest.raises(PolicyError, match="layout 'hcw'; valid: .'chw', 'hwc'."):
            load_policy(fmt.save(tmp_path / f"p{fmt.suffix}", program, _meta((4, 4, 3), 48)))


# ---- whole actors -------------------------------------------------------------------------------
def _torch_policy(policy: Any) -> TorchPolicy:
    """A ``TorchPolicy`` around an SB3 policy built in the test (no model, no run dir)."""
    model = SimpleNamespace(policy=policy, predict=policy.predict)
    return TorchPolicy(model, None, _meta(FRAME, 1, n_actions=7), None)


def _asymmetric(base: str, **kw: Any) -> Any:
    from sim2real.train.asymmetric import AsymmetricActorCriticPolicy

    kwargs = resolve_policy_kwargs({"features_extractor": base}, shift_px=4, pixel_actor=True)
    space = gym.spaces.Dict({PIXELS_KEY: CHW, PRIVILEGED_KEY: PRIVILEGED, **kw})
    return AsymmetricActorCriticPolicy(space, gym.spaces.Discrete(7), lambda _: 1e-3, **kwargs)


def _keypoint_actor() -> Any:
    policy = _asymmetric("keypoint_cnn")
    with th.no_grad():
        policy.pi_features_extractor.cnn.log_temperature.fill_(-0.7)  # a trained, sharp map
    return policy


def _nature_actor() -> Any:
    return _asymmetric("nature_cnn")


def _sb3_cnn_policy() -> Any:
    from stable_baselines3.common.policies import ActorCriticCnnPolicy

    return ActorCriticCnnPolicy(CHW, gym.spaces.Discrete(7), lambda _: 1e-3)


def _sb3_dqn_policy() -> Any:
    from stable_baselines3.dqn.policies import CnnPolicy

    return CnnPolicy(CHW, gym.spaces.Discrete(7), lambda _: 1e-3)


def _sb3_mlp_on_pixels() -> Any:
    from stable_baselines3.common.policies import ActorCriticPolicy

    return ActorCriticPolicy(CHW, gym.spaces.Discrete(7), lambda _: 1e-3, net_arch=[16])


ACTORS = {
    "keypoint_cnn (distill, asymmetric)": _keypoint_actor,
    "nature_cnn (asymmetric)": _nature_actor,
    "sb3 CnnPolicy (ppo, a2c)": _sb3_cnn_policy,
    "sb3 dqn CnnPolicy": _sb3_dqn_policy,
    "sb3 MlpPolicy on pixels": _sb3_mlp_on_pixels,
}


def _sharpened(policy: Any, frames: np.ndarray) -> TorchPolicy:
    """The policy with its last layer centred on ``frames``' features and scaled up: SB3
    initialises it to near-equal scores, dominated by the features' common mean, where every
    frame would get one action, or the argmax would test float noise rather than the export."""
    tp = _torch_policy(policy)
    last = policy.q_net.q_net[-1] if hasattr(policy, "q_net") else policy.action_net
    seen: list[th.Tensor] = []
    hook = last.register_forward_pre_hook(lambda _, args: seen.append(args[0]))
    tp.scores(frames)
    hook.remove()
    with th.no_grad():
        last.weight.mul_(100.0)
        last.bias.copy_(-last.weight @ seen[0].mean(dim=0))
    return tp


@pytest.mark.parametrize("name", sorted(ACTORS))
def test_pixel_actor_chooses_torchs_action_on_every_frame(name: str, tmp_path: Path) -> None:
    th.manual_seed(0)
    frames = _frames(64)
    tp = _sharpened(ACTORS[name](), frames)
    program = build_program(tp)
    assert program[0]["op"] == "image" and program[0]["layout"] == "hwc"
    assert program[-1] == {"op": "argmax"}
    ref, ref_scores = tp(frames), tp.scores(frames)
    assert ref_scores is not None and ref_scores.shape == (64, 7)
    assert len(np.unique(ref)) > 1  # the frames make it choose, not a constant
    for fmt, exported in _exported(program, tp.meta, tmp_path).items():
        got = exported(frames)
        assert got.shape == (64, 1) and got.dtype == np.float32, fmt
        np.testing.assert_array_equal(got, ref, err_msg=fmt)
        np.testing.assert_allclose(exported.scores(frames), ref_scores, atol=SCORE_TOLERANCE)


def test_keypoint_actor_leaves_the_random_shift_and_the_critic_out() -> None:
    th.manual_seed(0)
    program = build_program(_torch_policy(_keypoint_actor()))
    kinds = [op["op"] for op in program]
    assert kinds == [
        "image", "coord_concat",
        "conv2d", "act", "conv2d", "act", "conv2d",
        "keypoints", "dense", "act", "dense", "argmax",
    ]  # fmt: skip
    assert program[-2]["weight"].shape == (7, 128)  # net_arch []: the head reads the features
    np.testing.assert_allclose(program[7]["temperature"], np.exp(np.float32(-0.7)), rtol=1e-6)


def test_discrete_export_drives_the_kuka_env(tmp_path: Path) -> None:
    """``evaluate`` steps the env with the policy's (1,) float32 output: an index in [0, 7)."""
    import sim2real.envs as envs
    from sim2real.evaluate.rollout import run_episodes

    th.manual_seed(0)
    tp = _sharpened(_keypoint_actor(), _frames(16))
    exported = _exported(build_program(tp), tp.meta, tmp_path)["numpy"]
    seen: list[np.ndarray] = []
    result = run_episodes(
        exported,
        lambda: envs.make(KUKA, dr="none"),
        seeds=[10_000, 10_001],
        n_parallel=2,
        on_transition=lambda t: seen.append(t.action),
    )
    assert result.n == 2 and all(e.length > 0 for e in result.episodes)
    actions = np.array(seen)
    assert actions.shape == (len(seen), 1)
    assert np.all((actions >= 0) & (actions < 7) & (actions == np.round(actions)))


def test_parity_report_counts_disagreements_and_the_score_gap(tmp_path: Path) -> None:
    from sim2real.evaluate.parity import parity_report

    th.manual_seed(0)
    frames = _frames(40)
    tp = _sharpened(_nature_actor(), frames)
    program = build_program(tp)
    files = {
        name: fmt.save(tmp_path / f"p{fmt.suffix}", program, tp.meta)
        for name, fmt in FORMATS.items()
    }
    same = parity_report(files["numpy"], files["onnx"], frames)
    assert same.observations == 40 and same.action_disagreements == 0
    assert same.max_abs_action_diff == 0.0
    assert same.max_abs_score_diff is not None and same.max_abs_score_diff < SCORE_TOLERANCE
    program[-2] = {**program[-2], "bias": program[-2]["bias"] + np.arange(7, dtype=np.float32)}
    other = FORMATS["numpy"].save(tmp_path / "other.npz", program, tp.meta)
    report = parity_report(files["onnx"], other, frames)
    assert report.action_disagreements and report.max_abs_score_diff == pytest.approx(6.0)


# ---- what stays unsupported ---------------------------------------------------------------------
class _FrameAndJoints(gym.Env[dict[str, np.ndarray], np.ndarray]):
    """The spaces of a pixel env with two proprioceptive keys, one sorting before the frame,
    for a real VecNormalize to wrap."""

    observation_space = gym.spaces.Dict(
        {
            "arm": gym.spaces.Box(-np.inf, np.inf, (3,), np.float32),
            PIXELS_KEY: gym.spaces.Box(0, 255, FRAME, np.uint8),
            "proprio": gym.spaces.Box(-np.inf, np.inf, (9,), np.float32),
        }
    )
    action_space = gym.spaces.Box(-1, 1, (3,), np.float32)


def _frame_and_joints(recorded_shapes: bool, normalized: list[str]) -> TorchPolicy:
    """A pixel actor reading ``arm`` and ``proprio`` beside the frame, VecNormalize on
    ``normalized``, its record listing the keys arm, pixels, proprio (the frame in the middle)."""
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from sim2real.train.asymmetric import AsymmetricActorCriticPolicy

    th.manual_seed(0)
    env_spaces = _FrameAndJoints.observation_space.spaces
    kwargs = resolve_policy_kwargs({"features_extractor": "keypoint_cnn"}, 2, pixel_actor=True)
    space = gym.spaces.Dict({**env_spaces, PIXELS_KEY: CHW, PRIVILEGED_KEY: PRIVILEGED})
    policy = AsymmetricActorCriticPolicy(
        space, _FrameAndJoints.action_space, lambda _: 1e-3, **kwargs
    )
    vn = VecNormalize(DummyVecEnv([_FrameAndJoints]), norm_obs_keys=normalized, clip_obs=5.0)
    for key in normalized:
        n = env_spaces[key].shape[0]
        vn.obs_rms[key].mean = np.linspace(-1, 1, n)
        vn.obs_rms[key].var = np.linspace(0.5, 2, n)
    size = int(np.prod(FRAME))
    meta = _meta(
        (3 + size + 9,),
        3,
        obs_keys=("arm", PIXELS_KEY, "proprio"),
        obs_key_sizes=(3, size, 9),
        obs_key_shapes=((3,), FRAME, (9,)) if recorded_shapes else None,
    )
    model = SimpleNamespace(policy=policy, predict=policy.predict, observation_space=space)
    return TorchPolicy(model, vn, meta, None)


@pytest.mark.parametrize("recorded_shapes", [True, False])
def test_pixel_actor_with_proprioception_exports_the_image_and_its_keys_apart(
    recorded_shapes: bool, tmp_path: Path
) -> None:
    """The frame and each (normalised) proprioceptive key are read as their own column ranges
    of the flat input, the normaliser's clip never touches the pixels, and the continuous
    action is torch's on every observation, a batch of one and a single one, whether the
    record names each key's shape or predates it."""
    tp = _frame_and_joints(recorded_shapes, ["arm", "proprio"])
    rng = np.random.default_rng(1)
    obs = {
        "arm": rng.normal(0, 8, (32, 3)).astype(np.float32),
        PIXELS_KEY: _frames(32),
        "proprio": rng.normal(0, 8, (32, 9)).astype(np.float32),
    }
    want = tp(obs)
    program = build_program(tp)
    assert [op["op"] for op in program[:2]] == ["store", "load"]
    (norm,) = [op for op in program if op["op"] == "normalize"]
    assert norm["mean"].shape == (12,)  # arm and proprio, never the frame
    assert program[-3]["op"] == "append" and program[-1]["op"] == "clip"
    one = {k: v[0] for k, v in obs.items()}  # one observation: the frame is (H, W, C)
    first = {k: v[:1] for k, v in obs.items()}  # a batch of one
    for name, exported in _exported(program, tp.meta, tmp_path).items():
        np.testing.assert_allclose(exported(obs), want, atol=1e-5, err_msg=name)
        np.testing.assert_allclose(exported(one), want[0], atol=1e-5, err_msg=name)
        np.testing.assert_allclose(exported(first), want[:1], atol=1e-5, err_msg=name)
        with pytest.raises(PolicyError, match=r"key 'proprio' has shape \(32, 8\)"):
            exported({**obs, "proprio": obs["proprio"][:, :8]})
    # each key matters: changing either moves the action
    for key in ("arm", "proprio"):
        moved = tp({**obs, key: obs[key] * 0})
        assert np.abs(moved - want).max() > 1e-3, key


def test_a_proprioceptive_key_vecnormalize_leaves_raw_is_refused() -> None:
    """The op's clip would touch it where VecNormalize passes it through."""
    with pytest.raises(PolicyError, match=r"keys \['arm'\] beside an image that VecNormalize"):
        build_program(_frame_and_joints(True, ["proprio"]))


@pytest.mark.parametrize(
    ("op", "message"),
    [
        ({"op": "load", "name": "obs", "start": 0, "stop": 3}, "reads slot 'obs' before a store"),
        ({"op": "store"}, "has slot name None"),
        ({"op": "append", "name": "x", "start": 2, "stop": 2}, r"reads columns \[2, 2\)"),
        ({"op": "load", "name": "x", "stop": 2}, r"reads columns \[None, 2\)"),
    ],
)
def test_a_bad_slot_op_is_refused_in_one_line(op: Op, message: str, tmp_path: Path) -> None:
    program: list[Op] = [{"op": "store", "name": "x"}, op] if op.get("name") != "obs" else [op]
    FORMATS["numpy"].save(tmp_path / "p.npz", program, _meta((3,), 3))
    with pytest.raises(PolicyError, match=message) as info:
        load_policy(tmp_path / "p.npz")
    assert "\n" not in str(info.value)


def test_sb3_combined_extractor_with_an_image_is_refused() -> None:
    from stable_baselines3.common.policies import MultiInputActorCriticPolicy

    space = gym.spaces.Dict({"image": CHW, "joints": gym.spaces.Box(-3, 3, (3,), np.float32)})
    policy = MultiInputActorCriticPolicy(space, gym.spaces.Discrete(7), lambda _: 1e-3)
    with pytest.raises(PolicyError, match=r"keys \['image'\] are not flattened"):
        build_program(_torch_policy(policy))


def test_an_unknown_extractor_is_refused_naming_the_exportable_ones() -> None:
    from stable_baselines3.common.policies import ActorCriticCnnPolicy
    from stable_baselines3.common.torch_layers import NatureCNN

    class WiderCNN(NatureCNN):  # a subclass may compute something else: never matched
        pass

    policy = ActorCriticCnnPolicy(
        CHW, gym.spaces.Discrete(7), lambda _: 1e-3, features_extractor_class=WiderCNN
    )
    with pytest.raises(PolicyError, match="WiderCNN feature extractor; exportable: .*KeypointCNN"):
        build_program(_torch_policy(policy))
