"""sim2real: train a policy in domain-randomised simulation, run the same policy on a servo arm."""

import os

# Rendering is headless: EGL (Mesa here) unless the user chose otherwise. Must precede mujoco.
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

__version__ = "0.1.0"
