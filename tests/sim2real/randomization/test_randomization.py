"""DR: presets load and validate, sampling is seeded and in range, restore is bit-exact."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np
import pytest
import yaml

import sim2real.envs  # noqa: F401
from hardware.spec import load_spec
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.model import build_model
from sim2real.randomization import CATEGORIES, load_preset, preset_names
from sim2real.randomization.config import NEUTRAL, PRESET_DIR


def _model_arrays(model: mujoco.MjModel) -> dict[str, np.ndarray]:
    out = {}
    for name in dir(model):
        if name.startswith("_"):
            continue
        value = getattr(model, name)
        if isinstance(value, np.ndarray):
            out[name] = value.copy()
    return out


@pytest.mark.parametrize("env_id", ["Sim2Real/Arm3Pick-v0", "Sim2Real/Arm3Reach-v0"])
def test_restore_nominal_is_bit_identical_to_a_fresh_model(env_id: str) -> None:
    env = gym.make(env_id, dr="strong")
    u = env.unwrapped
    for seed in range(8):
        env.reset(seed=seed)
        for _ in range(5):
            env.step(env.action_space.sample())
    changed = _model_arrays(u.model)
    fresh = _model_arrays(build_model(load_spec(), u.task.scene, u.rig))
    assert any(not np.array_equal(changed[k], fresh[k]) for k in fresh)  # DR did change it
    u.restore_nominal()
    after = _model_arrays(u.model)
    for key, value in fresh.items():
        np.testing.assert_array_equal(after[key], value, err_msg=key)
    env.close()


def test_dr_params_are_seeded_in_range_and_reported_at_reset() -> None:
    env = gym.make("Sim2Real/Arm3Pick-v0", dr="default")
    _, info_a = env.reset(seed=11)
    _, info_b = env.reset(seed=11)
    _, info_c = env.reset(seed=12)
    cfg = load_preset("default")
    dyn = info_a["dr"]["dynamics"]
    np.testing.assert_array_equal(
        dyn["link_mass_scale"], info_b["dr"]["dynamics"]["link_mass_scale"]
    )
    assert not np.array_equal(dyn["link_mass_scale"], info_c["dr"]["dynamics"]["link_mass_scale"])
    for key in ("link_mass_scale", "joint_damping_scale", "actuator_gain_scale"):
        r = cfg["dynamics"][key]
        assert np.all((r.low <= dyn[key]) & (dyn[key] <= r.high)), key
    act = info_a["dr"]["actuation"]
    assert cfg["actuation"]["latency_steps"].low <= act["latency_steps"] <= 1
    # The sampled values really are in the model.
    u = env.unwrapped
    g = u.ids.cube_geom
    size = info_c["dr"]["object"]["size_scale"] * u.randomizer.nominal["geom_size"][g]
    np.testing.assert_allclose(u.model.geom_size[g], size)
    env.close()


def test_every_preset_loads_and_covers_every_category() -> None:
    assert set(preset_names()) >= {"none", "default", "strong", "shifted"}
    for name in preset_names():
        cfg = load_preset(name)
        assert set(cfg.ranges) == set(CATEGORIES)
    assert all(load_preset("none").is_neutral(c) for c in CATEGORIES)


def test_shifted_lies_outside_the_default_ranges() -> None:
    default, shifted = load_preset("default"), load_preset("shifted")
    outside = 0
    for cat, keys in default.ranges.items():
        for key, r in keys.items():
            s = shifted[cat][key]
            if s.high > r.high or s.low < r.low:
                outside += 1
            elif key.endswith("_prob") and r.high == 1.0:
                assert s.low == 1.0, key  # a probability already at 1 can only be pinned there
                outside += 1
    # Every axis that default randomises is pushed out, except fixed servo resolution.
    randomised = sum(
        1 for keys in default.ranges.values() for r in keys.values() if not r.is_neutral_point
    )
    assert outside >= randomised - 1


def test_every_range_key_has_a_unit_and_a_comment_in_default_yaml() -> None:
    text = (PRESET_DIR / "default.yaml").read_text().splitlines()
    for cat, keys in NEUTRAL.items():
        for key in keys:
            assert key.endswith(
                (
                    "_scale",
                    "_nm",
                    "_rad",
                    "_px",
                    "_m",
                    "_steps",
                    "_deg",
                    "jitter",
                    "friction",
                    "_prob",
                )
            ), key
            line = next(line for line in text if line.strip().startswith(f"{key}:"))
            assert "#" in line, f"{cat}.{key} has no provenance comment"


def test_bad_presets_are_rejected_with_the_value(tmp_path: Path) -> None:
    with pytest.raises(UnknownNameError, match="unknown DR preset 'wild'"):
        load_preset("wild")
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"dynamics": {"link_mass_scale": [1.2, 0.8]}}))
    with pytest.raises(ConfigError, match=r"\[1.2, 0.8\] has low > high"):
        load_preset(bad)
    bad.write_text(yaml.safe_dump({"dynamics": {"link_mas_scale": [1, 1]}}))
    with pytest.raises(ConfigError, match="unknown dynamics key.*link_mas_scale"):
        load_preset(bad)
    bad.write_text(yaml.safe_dump({"sensing": {"joint_noise_rad": [-0.1, 0.1]}}))
    with pytest.raises(ConfigError, match="joint_noise_rad low -0.1 must be >= 0"):
        load_preset(bad)
