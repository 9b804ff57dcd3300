"""Continuous distillation on the arm's pixel reach: the reach teacher labels the student's own
states with joint-delta actions, the student's Gaussian mean is fitted to them, and a run with a
frame-plus-proprioception observation evaluates from its run dir.

Runs use ``dr=none`` and 48x48 frames: the tests exercise the method, not its figures (those are
``bench/reach_teacher.py`` and ``bench/reach_pixels_learnability.py``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.logger import KVWriter, Logger

import sim2real.envs as envs
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.evaluate import EvalTarget, evaluate
from sim2real.export import export_policy, load_policy
from sim2real.observation import PIXELS_KEY, PROPRIO_FIELDS, PROPRIO_KEY
from sim2real.train import ALGOS, RunDir, resolve_config, train
from sim2real.train.augment import PRIVILEGED_KEY
from sim2real.train.distill import AGREEMENT_TOL, TEACHERS, Distill, get_teacher
from sim2real.train.factory import build_vec_env, transpose_images
from sim2real.train.wrappers import PrivilegedObservation

SMALL = {"dr": "none", "image_size": 48, "proprio": list(PROPRIO_FIELDS)}


class _Records(KVWriter):
    """Every logger dump, as a dict."""

    def __init__(self) -> None:
        self.rows: list[dict[str, Any]] = []

    def write(self, key_values: dict[str, Any], key_excluded: Any, step: int = 0) -> None:
        self.rows.append(dict(key_values))


def _venv(n: int = 2, **kwargs: Any) -> Any:
    env_kwargs = {**SMALL, **kwargs}
    return transpose_images(
        build_vec_env("reach-pixels", env_kwargs, list(range(n)), privileged=True)
    )


def test_the_privileged_wrapper_adds_its_key_to_a_dict_observation() -> None:
    env = PrivilegedObservation(envs.make("reach-pixels", **SMALL))
    try:
        assert set(env.observation_space.spaces) == {PIXELS_KEY, PROPRIO_KEY, PRIVILEGED_KEY}  # type: ignore[attr-defined]
        obs, info = env.reset(seed=0)
        np.testing.assert_array_equal(obs[PRIVILEGED_KEY], info["privileged_state"])
        assert obs[PROPRIO_KEY].shape == (9,) and obs[PIXELS_KEY].shape == (48, 48, 3)
        with pytest.raises(ConfigError, match="already has a 'privileged' key"):
            PrivilegedObservation(env)
    finally:
        env.close()


def test_the_reach_teacher_is_built_for_the_envs_own_step_size() -> None:
    assert {"kuka_scripted", "reach_ik", "reach_servo"} <= set(TEACHERS)
    env = envs.make("reach-pixels", dr="none", max_delta_rad=0.05)
    try:
        _, info = env.reset(seed=0)
        priv = info["privileged_state"]
        fine = get_teacher("reach_ik", env.unwrapped.decoder)  # type: ignore[attr-defined]
        nominal = get_teacher("reach_ik")  # the shipped arm at the default 0.1 rad step
        assert fine.continuous and fine.n_inputs == 6
        small = np.abs(nominal.action(priv)) < 0.5
        np.testing.assert_allclose(
            fine.action(priv)[small], 2 * nominal.action(priv)[small], rtol=1e-5
        )
    finally:
        env.close()
    with pytest.raises(
        UnknownNameError,
        match="unknown teacher 'oracle'; valid: kuka_scripted, pick_ddpg, pick_ppo, pick_servo, reach_ik",
    ):
        get_teacher("oracle")


def test_continuous_distill_student_closes_in_on_the_teacher_over_a_few_iterations() -> None:
    venv = _venv()
    th.manual_seed(0)
    model = Distill(
        "MultiInputPolicy",
        venv,
        teacher="reach_ik",
        n_steps=16,
        batch_size=64,
        gradient_steps=12,
        learning_rate=1e-3,
        dataset_size=512,
        policy_kwargs={"net_arch": [64], "log_std_init": -2.3},
        seed=0,
        device="cpu",
    )
    records = _Records()
    model.set_logger(Logger(folder=None, output_formats=[records]))
    model.learn(6 * 2 * 16, log_interval=1)  # six iterations of 2 envs x 16 steps
    rows = [r for r in records.rows if "train/batch_action_error" in r]
    assert len(rows) >= 5
    errors = [r["train/batch_action_error"] for r in rows]
    assert errors[-1] < 0.6 * errors[0], errors  # the mean moves onto the teacher's actions
    assert all(r["train/std"] == pytest.approx(np.exp(-2.3), rel=1e-5) for r in rows)  # fixed σ
    assert all(0.0 <= r["train/teacher_agreement"] <= 1.0 for r in rows)

    # The labels are the teacher's actions on the rollout's own (privileged) states.
    buf = model.rollout_buffer.observations
    assert isinstance(buf, dict)
    priv = buf[PRIVILEGED_KEY].reshape(-1, model.observation_space[PRIVILEGED_KEY].shape[0])  # type: ignore[index]
    teacher = get_teacher("reach_ik", venv.get_attr("decoder", [0])[0])
    newest = (np.arange(32) + model._data_pos - 32) % model.dataset_size
    np.testing.assert_allclose(model._labels[newest], [teacher.action(p) for p in priv], rtol=1e-6)
    assert model._labels.dtype == np.float32 and model._data[PROPRIO_KEY].shape == (512, 9)
    executed = np.clip(model.rollout_buffer.actions.reshape(-1, 3), -1.0, 1.0)
    agree = np.all(np.abs(executed - model._labels[newest]) <= AGREEMENT_TOL, axis=1).mean()
    assert (
        model._agreement(model.rollout_buffer.actions.reshape(-1, 3), model._labels[newest]).mean()
        == agree
    )
    venv.close()


def test_a_teacher_refuses_the_other_kind_of_action_space_and_an_entropy_bonus() -> None:
    venv = _venv(n=1)
    try:
        with pytest.raises(ConfigError, match="teacher 'kuka_scripted' acts in a Discrete space"):
            Distill("MultiInputPolicy", venv, teacher="kuka_scripted", device="cpu")
        with pytest.raises(ConfigError, match="ent_coef must be 0 for the continuous teacher"):
            Distill("MultiInputPolicy", venv, teacher="reach_ik", ent_coef=0.01, device="cpu")
    finally:
        venv.close()


def test_the_preset_trains_in_the_envs_own_actions_and_evaluates_from_its_run_dir(
    tmp_path: Path,
) -> None:
    run_dir = tmp_path / "run"
    cfg = resolve_config(
        "reach-pixels",
        "distill",
        run_dir,
        dr="none",
        steps=64,
        preset="distill_reach_pixels",
        progress=False,
        overrides=[
            "n_envs=2",
            "n_steps=16",
            "gradient_steps=2",
            "batch_size=16",
            "env_kwargs.image_size=48",
            "log_interval=1",
            "checkpoint_every=10000",
        ],
    )
    assert cfg.env_kwargs["success_threshold_m"] == 0.02
    assert cfg.hyperparams["teacher"] == "reach_servo"
    train(cfg)
    config = RunDir(run_dir).read_config()
    assert config["action_table"] is None and config["obs_keys"] == [PIXELS_KEY, PROPRIO_KEY]
    rows = [json.loads(line) for line in RunDir(run_dir).metrics_path.read_text().splitlines()]
    assert set(ALGOS["distill"].diagnostics) <= set().union(*rows)

    # The Policy interface flattens the Dict (the frame included): the run's policy must act on
    # it exactly as the model acts on the env's own observation.
    policy = load_policy(run_dir)
    model = Distill.load(str(RunDir(run_dir).model_path), device="cpu")
    env = envs.make("reach-pixels", dr="none", **cfg.env_kwargs)
    try:
        obs, _ = env.reset(seed=7)
        moved, *_ = env.step(np.ones(3, dtype=np.float32))  # a second, different frame
        batch = {k: np.stack([v, moved[k]]) for k, v in obs.items()}
        expect, _ = model.predict(batch, deterministic=True)
        np.testing.assert_allclose(policy(batch), expect, atol=1e-6)
    finally:
        env.close()
    result = evaluate(EvalTarget.load(run_dir), episodes=2, dr="none")
    assert result["episodes"] == 2 and result["algo"] == "distill"
    assert config["obs_key_shapes"] == [[48, 48, 3], [9]]  # joint_pos, joint_target, prev_action

    # Exported (the image and the proprioception read apart), it acts as the run does on the
    # env's frames, and evaluates from the file alone.
    for fmt, suffix in (("onnx", ".onnx"), ("numpy", ".npz")):
        exported = load_policy(export_policy(run_dir, fmt, tmp_path / f"reach{suffix}"))
        np.testing.assert_allclose(exported(batch), expect, atol=1e-5, err_msg=fmt)
    result = evaluate(EvalTarget.load(tmp_path / "reach.onnx"), episodes=2, dr="none")
    assert result["episodes"] == 2 and result["env_id"] == config["env_id"]
