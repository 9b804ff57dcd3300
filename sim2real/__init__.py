"""sim2real: train a policy in domain-randomised simulation, run the same policy on a servo arm.

Importing the package registers every Gymnasium id (``Sim2Real/...``), as Gymnasium plugin
packages do, so ``gym.make("Sim2Real/Arm3Reach-v0")`` and tools that import a package by name
find them. Registration imports no MuJoCo, torch or robosuite: the envs load when one is made.
"""

import importlib.util
import os

# Rendering is headless: EGL (Mesa here) unless the user chose otherwise. Must precede mujoco.
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

__version__ = "0.1.0"

# The ids need Gymnasium; a deploy-only install (hardware + ONNX policy) may lack it.
if importlib.util.find_spec("gymnasium") is not None:
    from sim2real.envs import register_all as _register_all

    _register_all()
