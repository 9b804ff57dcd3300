"""``sim2real envs`` end to end through the console entry point."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hardware.spec import DEFAULT_SPEC_PATH


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "sim2real", *args], capture_output=True, text=True, timeout=120
    )


def test_envs_lists_every_registered_id() -> None:
    out = _cli("envs", "--json")
    assert out.returncode == 0, out.stderr
    ids = [row["id"] for row in json.loads(out.stdout)]
    assert "Sim2Real/Arm3Reach-v0" in ids and "Sim2Real/Arm3Trace-v0" in ids


def test_envs_steps_one_env_and_prints_its_layout() -> None:
    out = _cli("envs", "pick", "--steps", "60", "--json")
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout)
    assert summary["id"] == "Sim2Real/Arm3Pick-v0" and summary["frame_skip"] == 10
    names = [f["name"] for f in summary["layout"]]
    assert names[:2] == ["joint_pos", "ee_pos"] and "cube_pos" in names


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["envs", "Arm3Fly"], "unknown env 'Arm3Fly'; valid:"),
        (["envs", "reach", "--dr", "wild"], "unknown DR preset 'wild'"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(args: list[str], message: str) -> None:
    out = _cli(*args)
    assert out.returncode == 2
    assert message in out.stderr and out.stderr.count("\n") == 1


def test_inverted_joint_limit_in_spec_is_named(tmp_path: Path) -> None:
    spec = tmp_path / "inverted.yaml"
    spec.write_text(DEFAULT_SPEC_PATH.read_text().replace("upper_rad: 1.4", "upper_rad: -1.4"))
    out = _cli("envs", "reach", "--spec", str(spec))
    assert out.returncode == 2
    assert "joint elbow: lower_rad (-0.9) must be below upper_rad (-1.4)" in out.stderr
