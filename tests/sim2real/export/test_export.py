"""Exported policies (ONNX, numpy) match the torch policy to 1e-5 and load without torch."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from hardware.spec import load_spec
from sim2real.evaluate.parity import PARITY_TOLERANCE, max_action_diff, sample_observations
from sim2real.export import PolicyError, export_policy, load_policy
from sim2real.train import resolve_config, train

torch.set_num_threads(1)

TINY: dict[str, list[str]] = {
    "ppo": ["n_steps=64", "batch_size=64", "n_epochs=2"],
    "ddpg": ["learning_starts=100", "buffer_size=1000", "batch_size=32", "gradient_steps=1"],
    "sac": ["learning_starts=100", "buffer_size=1000", "batch_size=32", "gradient_steps=1"],
    "dqn": ["learning_starts=100", "buffer_size=1000", "batch_size=32"],
}
CASES = [  # (algo, env, her, activation): every SB3 policy family the exporter handles
    ("ppo", "reach", False, "tanh"),
    ("ddpg", "reach", False, "relu"),
    ("sac", "reach-goal", True, "elu"),
    ("dqn", "reach", False, "leaky_relu"),
]


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("export")
    out = {}
    for algo, env, her, act in CASES:
        run = root / algo
        cfg = resolve_config(
            env,
            algo,
            run,
            steps=256,
            her=her,
            progress=False,
            overrides=[
                "n_envs=2",
                "policy_kwargs.net_arch=[32, 32]",
                f"policy_kwargs.activation_fn={act}",
                *TINY[algo],
            ],
        )
        train(cfg)
        out[algo] = run
    return out


@pytest.mark.parametrize("fmt", ["onnx", "numpy"])
@pytest.mark.parametrize("algo", [c[0] for c in CASES])
def test_export_matches_torch_within_1e5_on_1000_observations(
    runs: dict[str, Path], algo: str, fmt: str, tmp_path: Path
) -> None:
    out = export_policy(runs[algo], fmt, tmp_path / f"policy.{'onnx' if fmt == 'onnx' else 'npz'}")
    obs = sample_observations(runs[algo], 1000)
    diff = max_action_diff(runs[algo], out, obs)
    assert diff <= PARITY_TOLERANCE
    exported = load_policy(out)
    torch_policy = load_policy(runs[algo])
    a = exported(obs)
    assert a.shape == (1000, 3) and a.dtype == np.float32
    assert np.abs(a).max() <= 1.0 and a.std() > 0  # a real, non-constant policy
    assert exported.meta.spec_fingerprint == load_spec().fingerprint()
    assert exported.meta.env_id == torch_policy.meta.env_id
    assert exported.meta.obs_layout == torch_policy.meta.obs_layout
    assert exported.meta.exported_from == str(runs[algo]) and exported.meta.export_format == fmt


def test_normalisation_is_folded_in(runs: dict[str, Path], tmp_path: Path) -> None:
    """Raw observations go in: the exported file must hold the VecNormalize statistics."""
    from sim2real.export.program import load_npz

    out = export_policy(runs["ppo"], "numpy", tmp_path / "p.npz")
    program, _ = load_npz(out)
    norm = program[0]
    assert norm["op"] == "normalize" and norm["clip"] == 10.0
    assert not np.allclose(norm["mean"], 0.0) and not np.allclose(norm["std"], 1.0)


def test_numpy_policy_runs_without_torch_or_onnxruntime(
    runs: dict[str, Path], tmp_path: Path
) -> None:
    out = export_policy(runs["sac"], "numpy", tmp_path / "p.npz")
    obs = sample_observations(runs["sac"], 5)
    np.savez(tmp_path / "obs.npz", **obs)
    expected = load_policy(out)(obs)
    code = (
        "import sys, numpy as np\n"
        "for m in ('torch', 'onnxruntime', 'stable_baselines3', 'mujoco', 'gymnasium'):\n"
        "    sys.modules[m] = None  # any import of them now fails\n"
        "from sim2real.export import load_policy\n"
        f"p = load_policy({str(out)!r})\n"
        f"obs = dict(np.load({str(tmp_path / 'obs.npz')!r}))\n"
        "np.save(sys.argv[1], p(obs))\n"
    )
    result = tmp_path / "actions.npy"
    proc = subprocess.run(
        [sys.executable, "-c", code, str(result)], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0, proc.stderr
    np.testing.assert_array_equal(np.load(result), expected)


def test_policy_interface_rejects_bad_input(runs: dict[str, Path], tmp_path: Path) -> None:
    policy = load_policy(export_policy(runs["ppo"], "onnx", tmp_path / "p.onnx"))
    with pytest.raises(PolicyError, match=r"observation shape \(7,\) does not match"):
        policy(np.zeros(7, dtype=np.float32))
    with pytest.raises(PolicyError, match="NaN"):
        policy(np.full(policy.meta.flat_obs_dim, np.nan, dtype=np.float32))
    with pytest.raises(PolicyError, match="trained for arm spec"):
        policy.meta.check_spec("0000000000000000")
    layout = [(f.name, f.size) for f in policy.meta.obs_layout]
    policy.meta.check_layout(layout)  # its own layout passes
    swapped = [layout[1], layout[0], *layout[2:]]  # same size, other meaning: refused
    with pytest.raises(PolicyError, match="trained on observation layout"):
        policy.meta.check_layout(swapped)
    policy.meta.check_spec(load_spec().fingerprint())
    (tmp_path / "junk.onnx").write_bytes(b"not a model")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    for junk in ("junk.onnx", "junk.npz"):
        with pytest.raises(PolicyError, match="junk") as info:
            load_policy(tmp_path / junk)
        assert "\n" not in str(info.value)
    with pytest.raises(Exception, match="unknown policy file type '.pt'"):
        (tmp_path / "x.pt").write_bytes(b"")
        load_policy(tmp_path / "x.pt")


def test_pixel_run_exports_and_matches_torch_on_rendered_frames(tmp_path: Path) -> None:
    """SB3's CnnPolicy (NatureCNN) on the arm's 48 px camera, continuous actions; the discrete
    Kuka actors are tested op by op in ``test_pixels.py``."""
    run = tmp_path / "pix"
    cfg = resolve_config(
        "reach-pixels",
        "ppo",
        run,
        steps=32,
        progress=False,
        overrides=[
            "n_envs=1",
            "n_steps=32",
            "batch_size=32",
            "n_epochs=1",
            "env_kwargs.image_size=48",
        ],
    )
    train(cfg)
    obs = sample_observations(run, 64)
    assert obs.shape == (64, 48, 48, 3) and obs.dtype == np.uint8
    for fmt, suffix in (("onnx", ".onnx"), ("numpy", ".npz")):
        out = export_policy(run, fmt, tmp_path / f"p{suffix}")
        assert max_action_diff(run, out, obs) <= PARITY_TOLERANCE
        assert load_policy(out)(obs).shape == (64, 3)
