"""A script that renders and never closes its env exits quietly (no EGL traceback at exit)."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = """
import sim2real.envs
env = sim2real.envs.make("Sim2Real/Arm3ReachPixels-v0", image_size=48)
env.reset(seed=0)
env.step(env.action_space.sample())
print("stepped")
"""


def test_pixel_env_left_open_exits_without_egl_error() -> None:
    env = {**os.environ, "MUJOCO_GL": "egl", "PYOPENGL_PLATFORM": "egl"}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, timeout=300
    )
    assert out.returncode == 0, out.stderr
    assert "stepped" in out.stdout
    assert out.stderr == "", out.stderr
