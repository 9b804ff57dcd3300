"""The dagger stage: a state student of PPO or DDPG imitates the privileged pick teacher on the
realistic observation, and only there."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import sim2real.envs as envs
from sim2real.errors import ConfigError, Sim2RealError
from sim2real.evaluate import EvalTarget, evaluate
from sim2real.train import resolve_config, train
from sim2real.train.config import EVAL_SEED_BASE
from sim2real.train.dagger import Dagger

# What the arm's servos and cameras give the host, per observation field of the pick actor: a
# field added to the actor's observation must be added here, with what senses it.
SENSED_FIELDS = {
    "joint_pos": "the servo readings (joints, gripper)",
    "ee_pos": "the tool estimate (the wrist plate, or the spec's forward kinematics)",
    "cube_pos": "the cube tracker's estimate, held while hidden",
    "cube_delta": "cube estimate minus tool estimate",
    "cube_blind_s": "how long the cameras have not seen the cube",
    "goal_pos": "the lift goal latched from the first sighting",
    "goal_delta": "lift goal minus the grasp-aware cube estimate",
    "joint_target": "what the host commanded",
    "target_ee_pos": "forward kinematics of the command",
    "target_goal_delta": "lift goal minus that",
    "prev_action": "the policy's own last action",
}


@pytest.mark.parametrize(
    ("mapping", "message"),
    [
        ({"teacher": "oracle"}, "unknown dagger teacher 'oracle'; valid: kuka_scripted"),
        ({"iterations": 4}, "dagger needs a teacher"),
        ({"teacher": "pick_servo", "rounds": 4}, "dagger: unknown key(s) ['rounds']"),
        ({"teacher": "pick_servo", "iterations": 0}, "dagger.iterations must be an integer >= 1"),
        (
            {"teacher": "pick_servo", "iterations": 2, "teacher_iterations": 3},
            "teacher_iterations (3) must be <= iterations (2)",
        ),
        ({"teacher": "pick_servo", "noise_sigma": 2}, "dagger.noise_sigma must be in [0, 1]"),
        ({"teacher": "pick_servo", "anchor_every": 100}, "are both 0 (no anchor) or both >= 1"),
        ("pick_servo", "dagger must be a mapping"),
    ],
)
def test_bad_dagger_settings_are_refused_in_one_line(mapping: Any, message: str) -> None:
    with pytest.raises(Sim2RealError) as info:
        Dagger.from_mapping(mapping)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_dagger_is_for_state_students_of_ppo_a2c_ddpg_td3() -> None:
    with pytest.raises(ConfigError, match=r"dagger trains a student of \['a2c', 'ddpg', 'ppo', "):
        resolve_config("pick", "sac", "unused", overrides=["dagger.teacher=pick_servo"])


def test_the_pick_actor_observes_only_what_the_rig_senses() -> None:
    """Every field of the pick actor's observation is something the arm's host has; and the
    cube it observes is the tracker's: while the cameras cannot see it (occlusion certain at
    any distance here), moving the true cube changes nothing the actor sees."""
    env = envs.make("pick")
    u: Any = env.unwrapped
    try:
        names = [f.name for f in u.builder.layout()]
        assert set(names) <= set(SENSED_FIELDS), set(names) - set(SENSED_FIELDS)
        env.reset(seed=1)
        u.sensors.occlusion_radius_m, u.sensors.occlusion_prob = 10.0, 1.0
        u._configure_fused()
        obs, *_ = env.step(np.zeros(4, dtype=np.float32))
        cube = next(f for f in u.builder.layout() if f.name == "cube_pos")
        before = obs[cube.start : cube.stop].copy()
        u.data.qpos[u.task._cube_qadr : u.task._cube_qadr + 2] += 0.05  # the truth moves 5 cm
        for _ in range(4):
            obs, *_ = env.step(np.zeros(4, dtype=np.float32))
        np.testing.assert_array_equal(obs[cube.start : cube.stop], before)
    finally:
        env.close()


def _random_success(episodes: int) -> float:
    env = envs.make("pick", dr="none", safety_filter=True)
    rng = np.random.default_rng(0)
    wins = 0
    try:
        for j in range(episodes):
            env.reset(seed=EVAL_SEED_BASE + j)
            for _ in range(env.unwrapped.max_episode_steps):  # type: ignore[attr-defined]
                _, _, _, _, info = env.step(rng.uniform(-1, 1, 4).astype(np.float32))
            wins += bool(info["is_success"])
    finally:
        env.close()
    return wins / episodes


def test_a_short_dagger_run_learns_to_pick_where_chance_never_does(tmp_path: Path) -> None:
    """Six rounds of 1,000 labelled states (about 25 s on one core): a PPO student that picks
    at least 80 % of 40 held-out cubes under DR ``none`` (4 seeds measured 100 %), where random
    actions pick none. The run is an ordinary PPO run."""
    run = tmp_path / "run"
    overrides = [
        "dagger.iterations=6",
        "dagger.steps_per_iteration=125",
        "dagger.updates_per_iteration=500",
        "dagger.value_epochs=0",
        "dagger.anchor_every=0",
        "dagger.anchor_updates=0",
        "max_wall_s=0",
    ]
    cfg = resolve_config(
        "pick", "ppo", run, preset="ppo_pick", dr="none", steps=6000, overrides=overrides,
        progress=False,
    )  # fmt: skip
    train(cfg)
    figures = json.loads((run / "dagger.json").read_text())
    assert [r["acted"] for r in figures["iterations"]] == ["teacher"] + ["student"] * 5
    assert figures["transitions"] == 6000
    learned = evaluate(EvalTarget.load(run), 40)["success_rate"]
    assert learned >= 0.8
    assert _random_success(40) == 0.0


def test_the_anchor_keeps_imitating_while_ddpg_learns(tmp_path: Path) -> None:
    """Past the stage, the teacher labels what the learner visits and the anchor's minibatches
    run (``dagger/anchor_mse`` in the run's metrics)."""
    run = tmp_path / "run"
    overrides = [
        "dagger.iterations=2",
        "dagger.steps_per_iteration=25",
        "dagger.updates_per_iteration=20",
        "dagger.critic_updates=20",
        "dagger.anchor_every=80",
        "dagger.anchor_updates=5",
        "n_envs=4",
        "max_wall_s=0",
    ]
    cfg = resolve_config(
        "pick", "ddpg", run, preset="ddpg_pick", steps=400, overrides=overrides, progress=False
    )
    train(cfg)
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert any("dagger/anchor_mse" in r for r in rows)
    assert json.loads((run / "dagger.json").read_text())["critic_updates"] == 20
