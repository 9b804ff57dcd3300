"""The registered env ids as a plain table: which task, observation mode and entry point each
id names. Importing it needs neither Gymnasium nor MuJoCo, so the deploy runtime and the run
metadata reader can resolve an env id on a computer that cannot build the env;
``sim2real.envs`` registers these rows with Gymnasium.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from sim2real.errors import UnknownNameError

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


def entry(name: str) -> EnvEntry:
    """The table row of a full id or short name."""
    rid = resolve_env_id(name)
    return next(e for e in ENV_TABLE if e.id == rid)


def task_of(name: str) -> str:
    """The task an id runs (``reach``, ``pick``, ...); "" for an id without one."""
    return str(entry(name).kwargs.get("task", ""))


# Where each task's deploy contract lives (``sim2real.envs.contract``), as string entry points:
# deploy imports only the one it runs. Reach's imports no MuJoCo, so a reach policy deploys in
# the deploy profile; a test holds this table to the tasks' own ``contract`` attributes.
DEPLOY_CONTRACTS: dict[str, str] = {
    "reach": "sim2real.envs.reach_contract:ReachContract",
    "pick": "sim2real.envs.pick:PickContract",
    "trace": "sim2real.envs.trace:TraceContract",
}
