"""Registered environment ids (Gymnasium string entry points); importing registers them.

Each id is a (task, kwargs) row in ``ENV_TABLE``; ``sim2real envs`` prints it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym

from sim2real.envs import pick, reach, trace  # noqa: F401  (modules register their tasks)
from sim2real.envs.base import REWARDS, TASKS, Arm3Env, Arm3GoalEnv, Task, register_task
from sim2real.errors import UnknownNameError

ENTRY_POINT = "sim2real.envs.base:Arm3Env"
GOAL_ENTRY_POINT = "sim2real.envs.base:Arm3GoalEnv"
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
    ),
    EnvEntry(
        "Sim2Real/KukaGraspCont-v0",
        "kuka-cont",
        {"actions": "continuous"},
        entry_point=KUKA_ROBOSUITE_ENTRY_POINT,
        doc="grasp from 48x48 RGB, (dx, dy, dyaw) in [-1, 1], robosuite IIWA",
    ),
]


def register_all() -> None:
    """Register every id once (idempotent; other backends append rows before calling)."""
    for entry in ENV_TABLE:
        if entry.id not in gym.registry:
            gym.register(
                id=entry.id,
                entry_point=entry.entry_point,
                kwargs=dict(entry.kwargs),
                disable_env_checker=True,  # the contract tests run check_env on every id
            )


def env_ids() -> list[str]:
    return [e.id for e in ENV_TABLE]


def resolve_env_id(name: str) -> str:
    """A full id, or a short name such as ``reach`` / ``Arm3Reach``."""
    for e in ENV_TABLE:
        if name in (e.id, e.short, e.id.split("/")[-1].removesuffix("-v0")):
            return e.id
    raise UnknownNameError("env", name, [e.id for e in ENV_TABLE])


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
    "make",
    "register_task",
    "resolve_env_id",
]
