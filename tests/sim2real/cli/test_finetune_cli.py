"""``sim2real finetune`` refuses bad input in one line, before any process or port is opened."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from sim2real.cli.main import main


def _error(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    code = main(["finetune", *argv, "--no-keys"])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1, err
    return err


def test_unknown_algo_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    err = _error(capsys, "reach-ddpg", "--algo", "ppo", "--out", str(tmp_path / "o"))
    assert "'ppo'" in err and "ddpg" in err


def test_on_policy_source_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    err = _error(capsys, "reach-ppo", "--out", str(tmp_path / "o"))
    assert "'ppo'" in err and "off-policy" in err
    assert not (tmp_path / "o").exists()


def test_sac_cannot_continue_a_ddpg_checkpoint(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    err = _error(capsys, "reach-ddpg", "--algo", "sac", "--out", str(tmp_path / "o"))
    assert "sac" in err and "ddpg->td3" in err


def test_missing_policy_and_missing_checkpoint(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    err = _error(capsys, "no-such-policy", "--out", str(tmp_path / "o"))
    assert "'no-such-policy'" in err and "does not exist" in err

    # a run directory whose checkpoints are gone
    from sim2real.policies import shipped
    from sim2real.train.rundir import RunDir

    ckpt = shipped()["reach-ddpg"].checkpoint
    assert ckpt is not None
    run = RunDir(tmp_path / "run")
    run.path.mkdir()
    run.write_config(json.loads(ckpt[1].read_text())["config"])
    err = _error(capsys, str(run.path), "--out", str(tmp_path / "o"))
    assert "no checkpoint" in err and str(run.path) in err


def test_resume_without_a_checkpoint_and_a_busy_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "o"
    out.mkdir()
    (out / "something").write_text("x")
    err = _error(capsys, "reach-ddpg", "--out", str(out))
    assert "--resume" in err and "not empty" in err
    err = _error(capsys, "reach-ddpg", "--out", str(out), "--resume")
    assert "finetune.json" in err


@pytest.mark.parametrize(
    ("flag", "value"),
    [
        ("--minutes", "0"),
        ("--utd", "-1"),
        ("--backend", "sim"),
        ("--actor-starts", "-5"),
        ("--learning-rate", "2"),
        ("--noise-std", "1.5"),
        ("--imitation-ratio", "0"),
        ("--noise-corr-steps", "-1"),
        ("--gripper-noise-std", "3"),
    ],
)
def test_bad_numbers_and_backends(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], flag: str, value: str
) -> None:
    err = _error(capsys, "reach-ddpg", flag, value, "--out", str(tmp_path / "o"))
    assert flag in err and value in err
