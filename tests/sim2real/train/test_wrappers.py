"""The training-only start curriculum: what it draws, where it applies, what it refuses."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import sim2real.envs as envs
from hardware.spec import ArmSpec
from sim2real.errors import ConfigError, Sim2RealError
from sim2real.evaluate import EvalTarget
from sim2real.train import RunDir, resolve_config
from sim2real.train.config import EVAL_SEED_BASE, TrainConfig
from sim2real.train.wrappers import StartCurriculum


def _starts(env: StartCurriculum, n: int, seed: int = 0) -> list[str]:
    out = [env.reset(seed=seed)[1]["start"]]
    out += [env.reset()[1]["start"] for _ in range(n - 1)]
    return out


def test_the_curriculum_draws_held_starts_at_its_rate_from_its_own_generator() -> None:
    assert set(_starts(StartCurriculum(envs.make("pick"), 1.0), 5)) == {"held"}
    assert set(_starts(StartCurriculum(envs.make("pick"), 0.0), 5)) == {"default"}
    half = _starts(StartCurriculum(envs.make("pick"), 0.5), 80)
    assert 0.3 < half.count("held") / 80 < 0.7
    assert _starts(StartCurriculum(envs.make("pick"), 0.5), 80) == half  # seeded: reproducible
    # A held episode is really held; an explicit start option wins over the draw.
    env = StartCurriculum(envs.make("pick"), 1.0)
    env.reset(seed=3)
    assert env.unwrapped.task.is_grasped(env.unwrapped)  # type: ignore[attr-defined]
    assert env.reset(seed=3, options={"start": "default"})[1]["start"] == "default"
    # Same seed, same DR and cube as the bare env: the draw does not touch the env's stream.
    bare = envs.make("pick")
    for seed in range(4):
        _, info = env.reset(seed=seed, options={"start": "default"})
        _, bare_info = bare.reset(seed=seed)
        np.testing.assert_array_equal(
            env.unwrapped.task.cube_position(env.unwrapped),  # type: ignore[attr-defined]
            bare.unwrapped.task.cube_position(bare.unwrapped),  # type: ignore[attr-defined]
        )
        assert info["dr"]["object"]["mass_scale"] == bare_info["dr"]["object"]["mass_scale"]
    with pytest.raises(ConfigError, match="task 'reach' has no 'held' start"):
        StartCurriculum(envs.make("reach"), 0.5)


@pytest.mark.parametrize(
    ("env", "override", "message"),
    [
        ("pick", "start_curriculum.held_prob=1.5", "held_prob must be in [0, 1], got 1.5"),
        ("pick", "start_curriculum.held_prob=-0.1", "held_prob must be in [0, 1], got -0.1"),
        ("pick", "start_curriculum.held_prob=yes", "held_prob must be in [0, 1], got True"),
        ("pick", "start_curriculum={held: 0.5}", "start_curriculum: unknown key(s) ['held']"),
        ("pick", "start_curriculum=0.5", "start_curriculum must be a mapping"),
        ("reach", "start_curriculum.held_prob=0.5", "Arm3Reach-v0 has no 'held' start"),
        ("trace", "start_curriculum.held_prob=0.5", "Arm3Trace-v0 has no 'held' start"),
    ],
)
def test_bad_curricula_are_refused_in_one_line(env: str, override: str, message: str) -> None:
    with pytest.raises(Sim2RealError) as info:
        resolve_config(env, "ppo", "unused", overrides=[override])
    assert message in str(info.value) and "\n" not in str(info.value)


def test_a_pick_curriculum_survives_a_resume_round_trip() -> None:
    cfg = resolve_config("pick", "ppo", "unused", overrides=["start_curriculum.held_prob=0.5"])
    assert cfg.start_curriculum == {"held_prob": 0.5}
    assert TrainConfig.from_dict(cfg.to_dict()) == cfg
    assert resolve_config("reach", "ppo", "unused").start_curriculum is None


def test_the_curriculum_applies_to_training_envs_only(
    tmp_path: Path, tiny: Callable[..., Path]
) -> None:
    from sim2real.randomization import load_preset
    from sim2real.train.runner import _Session

    run = tmp_path / "run"
    # ppo_pick's DAgger stage cut to one short round: the curriculum is what is judged here
    dagger = [
        "dagger.iterations=1",
        "dagger.steps_per_iteration=8",
        "dagger.updates_per_iteration=1",
    ]
    tiny("ppo", run, env="pick", extra=["start_curriculum.held_prob=1.0", *dagger])
    config = RunDir(run).read_config()
    assert config["train"]["start_curriculum"] == {"held_prob": 1.0}
    # The training envs the runner builds start held ...
    cfg = TrainConfig.from_dict({**config["train"], "run_dir": str(tmp_path / "again")})
    spec = ArmSpec.from_dict(config["spec"])
    session = _Session(cfg, RunDir(cfg.run_dir), spec, load_preset(config["dr"]))
    venv = session.vec_env(None)
    venv.reset()
    assert all(e.unwrapped.task.is_grasped(e.unwrapped) for e in venv.unwrapped.envs)  # type: ignore[attr-defined]
    venv.close()
    # ... the env evaluation rebuilds from the run does not.
    target = EvalTarget.load(run)
    env = target.env_factory(target.train_dr)()
    for seed in range(EVAL_SEED_BASE, EVAL_SEED_BASE + 3):
        _, info = env.reset(seed=seed)
        assert info["start"] == "default"
        assert not env.unwrapped.task.is_grasped(env.unwrapped)  # type: ignore[attr-defined]
    env.close()
