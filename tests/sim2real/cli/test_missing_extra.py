"""A command whose install extra is missing says which extra to install, in one line.

The child interpreter really lacks the modules: a meta-path finder in front of every other one
refuses them, as an interpreter without the wheel would (the lean-venv test in
``tests/test_install_profiles.py`` checks the same on a real ``.[deploy]`` install).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
CHILD = """
import importlib.abc, sys
BLOCKED = set(sys.argv[1].split(","))

class Missing(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

sys.meta_path.insert(0, Missing())
from sim2real.cli.main import main
raise SystemExit(main(sys.argv[2:]))
"""


def _run(blocked: str, *argv: str, cwd: Path = REPO) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run(
        [sys.executable, "-c", CHILD, blocked, *argv],
        capture_output=True, text=True, env=env, timeout=300, cwd=cwd,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("blocked", "argv", "extra", "module"),
    [
        ("torch,stable_baselines3", ["train", "--env", "reach", "--steps", "8"], "train", "torch"),
        ("torch", ["export", "no-such-run"], "train", "torch"),
        ("mujoco", ["envs", "reach", "--steps", "1"], "sim", "mujoco"),
        ("scipy,numba", ["sysid", "no-such-log.npz"], "sim", "numba|scipy"),
        ("cv2", ["calibrate", "--help"], "deploy", "cv2"),
    ],
)
def test_missing_extra_is_named_in_one_line(
    tmp_path: Path, blocked: str, argv: list[str], extra: str, module: str
) -> None:
    res = _run(blocked, *argv, cwd=tmp_path)  # nothing is written into the repository
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2, res.stderr
    assert len(lines) == 1, res.stderr
    assert f"needs the '{extra}' extra" in lines[0]
    assert f"pip install 'sim2real[{extra}]'" in lines[0]
    assert any(m in lines[0] for m in module.split("|"))


def test_a_missing_module_no_extra_provides_is_a_traceback() -> None:
    """A missing project module is a bug, not a profile: it is not dressed up as one."""
    res = _run("hardware", "arm", "--help")
    assert res.returncode == 1
    assert "Traceback" in res.stderr and "hardware" in res.stderr
