"""Shipped policies: listed, loadable by name wherever a run directory is, fit a shipped arm (the
pot build, or the bare PWM build for the ``-pwm`` ones)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from hardware.spec import PWM_SPEC_PATH, load_spec
from sim2real import env_table
from sim2real.cli.main import main
from sim2real.deploy.policy_io import policy_io
from sim2real.errors import ConfigError
from sim2real.export.policy import load_policy
from sim2real.policies import resolve_policy, shipped

PIXEL_REACH = "reach-pixels-distill"


def test_every_shipped_arm_policy_fits_the_shipped_arm_and_its_task_contract() -> None:
    ships = shipped()
    assert {"reach-ppo", "reach-ddpg"} <= set(ships)
    pots = load_spec()
    pwm = load_spec(PWM_SPEC_PATH)
    arm = {n: s for n, s in ships.items() if s.task in env_table.DEPLOY_CONTRACTS}
    assert {"reach-ppo", "pick-ppo", "trace-ppo", PIXEL_REACH} <= set(arm)
    assert {"reach-ppo-pwm", "pick-ppo-pwm"} <= set(arm), "the default hobby build's policies"
    for name, ship in arm.items():
        policy = load_policy(name)  # by name
        if policy.meta.obs_mode == "pixels":  # deployed from camera frames: the test below
            continue
        spec = pwm if name.endswith("-pwm") else pots  # the name says the build
        policy.meta.check_spec(spec.fingerprint())
        io = policy_io(spec, policy.meta)  # layout checked field by field
        assert io.task == ship.task, name
        obs = np.zeros(io.builder.size, dtype=np.float32)
        action = policy(obs)
        assert action.shape == (io.decoder.n_actions,) and np.all(np.abs(action) <= 1.0)
        assert ship.path.stat().st_size < 5_000_000  # a few MB at most
        assert 0.0 <= ship.figures["env_success_dr_default"] <= 1.0


def test_a_shipped_pixel_policy_acts_on_its_envs_frames_and_refuses_to_deploy() -> None:
    """The Kuka student runs in simulation only: it loads by name, picks one of the env's
    discrete actions from the env's own frame, and the arm's deploy loop refuses it by name."""
    import gymnasium as gym

    ship = shipped()["kuka-distill"]
    assert ship.task not in env_table.DEPLOY_CONTRACTS
    assert ship.path.stat().st_size < 5_000_000
    policy = load_policy("kuka-distill")
    env = gym.make(ship.env_id)
    try:
        frame, _ = env.reset(seed=0)
        action = policy(frame)
        assert action.shape == (1,) and env.action_space.contains(int(action[0]))
        env.step(int(action[0]))
    finally:
        env.close()
    with pytest.raises(ConfigError, match="kuka-distill.onnx.*no deploy contract"):
        policy_io(load_spec(), policy.meta)


def test_the_shipped_arm_pixel_student_reaches_from_frames_and_joints_and_refuses_to_deploy() -> (
    None
):
    """The reach student acts on the env's own dict observation (the 84 px frame beside the
    joint readings) from its ONNX file alone, evaluates by name, and the state deploy loop
    refuses it in one line."""
    from sim2real.evaluate import EvalTarget, evaluate

    ship = shipped()[PIXEL_REACH]
    assert ship.path.suffix == ".onnx" and ship.path.stat().st_size < 5_000_000
    policy = load_policy(PIXEL_REACH)
    assert policy.meta.obs_keys == ("pixels", "proprio")
    result = evaluate(EvalTarget.load(PIXEL_REACH), episodes=2, dr="none")
    assert result["episodes"] == 2 and result["env_id"] == ship.env_id
    assert 0.0 <= result["median_final_distance_m"] < 0.5
    with pytest.raises(ConfigError, match="observes pixels"):
        policy_io(load_spec(), policy.meta)


def test_policies_cli_lists_and_shows_cards(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["policies", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert listed["reach-ppo"]["task"] == "reach"
    assert main(["policies", "reach-ddpg", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["algo"] == "ddpg"


def test_a_shipped_policy_deploys_by_name(capsys: pytest.CaptureFixture[str]) -> None:
    args = ["deploy", "reach-ppo", "--backend", "sim", "--sim-clock", "lockstep",
            "--episodes", "1", "--json"]  # fmt: skip
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert summary["task"] == "reach" and summary["episodes"] == 1


def test_an_unknown_policy_name_is_one_line_naming_it_and_the_shipped_ones() -> None:
    res = subprocess.run(
        [sys.executable, "-m", "sim2real", "deploy", "pick-sac", "--backend", "sim"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2
    assert res.stderr.count("\n") == 1, res.stderr
    assert "'pick-sac'" in res.stderr and "reach-ppo" in res.stderr
    with pytest.raises(Exception, match="shipped policies"):
        resolve_policy("pick-sac")
