"""Registered environment ids (Gymnasium string entry points); importing registers them.

Each id is a (task, kwargs) row in ``ENV_TABLE``; ``sim2real envs`` prints it. Registration is
cheap: ``import sim2real`` registers every id without importing MuJoCo, torch or robosuite. The
task classes (``Arm3Env``, ``TASKS``, ...) load on first use, through ``__getattr__`` below, and
the arm envs' entry points name them here (``sim2real.envs:Arm3Env``) so that making one also
imports the task modules that register themselves.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import gymnasium as gym
from gymnasium.envs.registration import WrapperSpec

from sim2real.errors import UnknownNameError

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


ENTRY_POINT = "sim2real.envs:Arm3Env"
GOAL_ENTRY_POINT = "sim2real.envs:Arm3GoalEnv"
ROBOSUITE_ENTRY_POINT = "sim2real.envs.robosuite_env:RobosuiteEnv"
KUKA_FAST_ENTRY_POINT = "sim2real.envs.kuka_grasp:KukaGraspFastEnv"
KUKA_ROBOSUITE_ENTRY_POINT = "sim2real.envs.kuka_robosuite:KukaGraspEnv"


@dataclass(frozen=True)
class EnvEntry:
    id: str
    short: str
    kwargs: dict[str, Any] = field(default_factory=dict)
    entry_point: str = ENTRY_POINT
    doc: str = ""
    discrete_actions: bool = False  # the env's own action space is Discrete (no wrapper needed)
    # Short name of another env whose tuned presets this one uses when it has none of its own:
    # the robosuite Kuka twin trains with the fast twin's, so a ranking check changes one thing.
    presets_from: str | None = None


ENV_TABLE: list[EnvEntry] = [
    EnvEntry("Sim2Real/Arm3Reach-v0", "reach", {"task": "reach"}, doc="state, dense reward"),
    EnvEntry(
        "Sim2Real/Arm3ReachSparse-v0",
        "reach-sparse",
        {"task": "reach", "reward": "sparse"},
        doc="state, sparse reward",
    ),
    EnvEntry(
        "Sim2Real/Arm3ReachGoal-v0",
        "reach-goal",
        {"task": "reach", "obs_mode": "goal", "reward": "sparse"},
        entry_point=GOAL_ENTRY_POINT,
        doc="Dict obs for HER",
    ),
    EnvEntry(
        "Sim2Real/Arm3ReachPixels-v0",
        "reach-pixels",
        {"task": "reach", "obs_mode": "pixels"},
        doc="84x84 RGB from cam_left",
    ),
    EnvEntry("Sim2Real/Arm3Pick-v0", "pick", {"task": "pick"}, doc="state, dense reward"),
    EnvEntry(
        "Sim2Real/Arm3PickGoal-v0",
        "pick-goal",
        {"task": "pick", "obs_mode": "goal", "reward": "sparse"},
        entry_point=GOAL_ENTRY_POINT,
        doc="Dict obs for HER",
    ),
    EnvEntry(
        "Sim2Real/Arm3PickPixels-v0",
        "pick-pixels",
        {"task": "pick", "obs_mode": "pixels"},
        doc="84x84 RGB from cam_left",
    ),
    EnvEntry("Sim2Real/Arm3Trace-v0", "trace", {"task": "trace"}, doc="follow a seam"),
    # robosuite backend: string entry points, so robosuite is imported only when one is made.
    EnvEntry(
        "Sim2Real/RobosuiteLift-v0",
        "robosuite-lift",
        {"task": "lift"},
        entry_point=ROBOSUITE_ENTRY_POINT,
        doc="robosuite Lift, Panda (robot=...), OSC_POSE",
    ),
    EnvEntry(
        "Sim2Real/RobosuiteReach-v0",
        "robosuite-reach",
        {"task": "reach"},
        entry_point=ROBOSUITE_ENTRY_POINT,
        doc="robosuite reach to 1 cm, Panda (robot=...), OSC_POSITION",
    ),
    # The seed project's Kuka grasping from 48x48 pixels (docs/kuka-grasp.md).
    EnvEntry(
        "Sim2Real/KukaGraspFast-v0",
        "kuka-fast",
        {"actions": "discrete"},
        entry_point=KUKA_FAST_ENTRY_POINT,
        doc="grasp from 48x48 RGB, 7 discrete actions, floating gripper (fast)",
        discrete_actions=True,
    ),
    EnvEntry(
        "Sim2Real/KukaGraspFastCont-v0",
        "kuka-fast-cont",
        {"actions": "continuous"},
        entry_point=KUKA_FAST_ENTRY_POINT,
        doc="grasp from 48x48 RGB, (dx, dy, dyaw) in [-1, 1], floating gripper (fast)",
    ),
    EnvEntry(
        "Sim2Real/KukaGrasp-v0",
        "kuka",
        {"actions": "discrete"},
        entry_point=KUKA_ROBOSUITE_ENTRY_POINT,
        doc="grasp from 48x48 RGB, 7 discrete actions, robosuite IIWA",
        discrete_actions=True,
        presets_from="kuka-fast",
    ),
    EnvEntry(
        "Sim2Real/KukaGraspCont-v0",
        "kuka-cont",
        {"actions": "continuous"},
        entry_point=KUKA_ROBOSUITE_ENTRY_POINT,
        doc="grasp from 48x48 RGB, (dx, dy, dyaw) in [-1, 1], robosuite IIWA",
    ),
]


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


_FORWARD_EPISODE_LENGTH = WrapperSpec(
    name="ForwardEpisodeLength",
    entry_point=f"{__name__}:forward_episode_length",
    kwargs={},
)


def register_all() -> None:
    """Register every id once (idempotent; other backends append rows before calling).

    No registered ``max_episode_steps``: each env truncates at its own length, and an explicit
    ``max_episode_steps`` reaches it, whether passed to ``gym.make`` (see
    ``forward_episode_length``) or as an env kwarg through an ``EnvSpec``.
    """
    for entry in ENV_TABLE:
        if entry.id not in gym.registry:
            gym.register(
                id=entry.id,
                entry_point=entry.entry_point,
                kwargs=dict(entry.kwargs),
                max_episode_steps=None,
                disable_env_checker=True,  # the contract tests run check_env on every id
                additional_wrappers=(_FORWARD_EPISODE_LENGTH,),
            )


def env_ids() -> list[str]:
    return [e.id for e in ENV_TABLE]


def resolve_env_id(name: str) -> str:
    """A full id, or a short name such as ``reach`` / ``Arm3Reach``."""
    for e in ENV_TABLE:
        if name in (e.id, e.short, e.id.split("/")[-1].removesuffix("-v0")):
            return e.id
    raise UnknownNameError("env", name, [e.id for e in ENV_TABLE])


def has_discrete_actions(name: str) -> bool:
    """Whether the id's own action space is ``Discrete`` (from the table: no env is built)."""
    rid = resolve_env_id(name)
    return next(e for e in ENV_TABLE if e.id == rid).discrete_actions


def make(name: str, **kwargs: Any) -> gym.Env[Any, Any]:
    """``gym.make`` with short names and one-line errors for unknown ids."""
    return gym.make(resolve_env_id(name), **kwargs)


register_all()

__all__ = [
    "ENV_TABLE",
    "REWARDS",
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
