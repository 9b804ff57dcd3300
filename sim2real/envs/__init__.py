"""Registered environment ids (Gymnasium string entry points); importing registers them.

Each id is a (task, kwargs) row in ``ENV_TABLE`` (``sim2real.env_table``, which imports no
Gymnasium); ``sim2real envs`` prints it. Registration is
cheap: ``import sim2real`` registers every id without importing MuJoCo, torch or robosuite. The
task classes (``Arm3Env``, ``TASKS``, ...) load on first use, through ``__getattr__`` below, and
the arm envs' entry points name them here (``sim2real.envs:Arm3Env``) so that making one also
imports the task modules that register themselves.
"""

from __future__ import annotations

import importlib
import importlib.util
from typing import TYPE_CHECKING, Any

from sim2real.env_table import (
    ENTRY_POINT,
    ENV_TABLE,
    GOAL_ENTRY_POINT,
    KUKA_FAST_ENTRY_POINT,
    KUKA_ROBOSUITE_ENTRY_POINT,
    ROBOSUITE_ENTRY_POINT,
    EnvEntry,
    env_ids,
    has_discrete_actions,
    resolve_env_id,
)

# The deploy profile has no Gymnasium: its task contracts still import from this package, the
# ids resolve through ``env_table``, and nothing is registered or built.
HAVE_GYMNASIUM = importlib.util.find_spec("gymnasium") is not None
if HAVE_GYMNASIUM or TYPE_CHECKING:
    import gymnasium as gym
    from gymnasium.envs.registration import WrapperSpec

if TYPE_CHECKING:
    from sim2real.envs.base import REWARDS, TASKS, Arm3Env, Arm3GoalEnv, Task, register_task

# Loaded on first access: the task modules import MuJoCo.
_LAZY_FROM_BASE = ("REWARDS", "TASKS", "Arm3Env", "Arm3GoalEnv", "Task", "register_task")
# The built-in tasks register themselves when their module is imported.
_TASK_MODULES = ("pick", "reach", "trace")


def __getattr__(name: str) -> Any:
    """PEP 562: ``sim2real.envs.Arm3Env`` (and the gym entry points) import the tasks lazily."""
    if name in _LAZY_FROM_BASE:
        for module in _TASK_MODULES:
            importlib.import_module(f"{__name__}.{module}")
        value = getattr(importlib.import_module(f"{__name__}.base"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def forward_episode_length(env: gym.Env[Any, Any]) -> gym.Env[Any, Any]:
    """Hand ``gym.make(id, max_episode_steps=N)``'s N down to the env itself.

    Gymnasium takes ``max_episode_steps`` as its own argument: the env is built with its default
    length and a ``TimeLimit`` cuts it at N. Our envs truncate (and Trace paces its seam, Kuka
    closes the gripper) at their own ``max_episode_steps``, so without this an N above the default
    is ignored and one below it ends episodes before the task's end-of-episode logic runs. It runs
    as the registered ids' additional wrapper (after ``TimeLimit``) and returns ``env`` unchanged;
    the N goes into the spec's kwargs too, so ``gym.make(env.spec)`` rebuilds the same env.
    """
    spec = env.spec  # TimeLimit's (cached) copy, carrying N
    steps = None if spec is None else spec.max_episode_steps
    base = env.unwrapped
    if spec is None or steps is None or not hasattr(base, "max_episode_steps"):
        return env
    base.max_episode_steps = int(steps)
    for s in (spec, base.spec):
        if s is not None:
            s.kwargs["max_episode_steps"] = int(steps)
    return env


def register_all() -> None:
    """Register every id once (idempotent; other backends append rows before calling).

    No registered ``max_episode_steps``: each env truncates at its own length, and an explicit
    ``max_episode_steps`` reaches it, whether passed to ``gym.make`` (see
    ``forward_episode_length``) or as an env kwarg through an ``EnvSpec``.
    """
    forward = WrapperSpec(
        name="ForwardEpisodeLength", entry_point=f"{__name__}:forward_episode_length", kwargs={}
    )
    for entry in ENV_TABLE:
        if entry.id not in gym.registry:
            gym.register(
                id=entry.id,
                entry_point=entry.entry_point,
                kwargs=dict(entry.kwargs),
                max_episode_steps=None,
                disable_env_checker=True,  # the contract tests run check_env on every id
                # the arm envs enforce reset-before-step themselves (``Arm3Env``)
                order_enforce=entry.entry_point not in (ENTRY_POINT, GOAL_ENTRY_POINT),
                additional_wrappers=(forward,),
            )


def make(name: str, **kwargs: Any) -> gym.Env[Any, Any]:
    """``gym.make`` with short names and one-line errors for unknown ids."""
    import gymnasium  # the sim extra: a missing one is named by the CLI

    return gymnasium.make(resolve_env_id(name), **kwargs)


if HAVE_GYMNASIUM:
    register_all()

__all__ = [
    "ENTRY_POINT",
    "ENV_TABLE",
    "GOAL_ENTRY_POINT",
    "KUKA_FAST_ENTRY_POINT",
    "KUKA_ROBOSUITE_ENTRY_POINT",
    "REWARDS",
    "ROBOSUITE_ENTRY_POINT",
    "TASKS",
    "Arm3Env",
    "Arm3GoalEnv",
    "EnvEntry",
    "Task",
    "env_ids",
    "forward_episode_length",
    "has_discrete_actions",
    "make",
    "register_task",
    "resolve_env_id",
]
