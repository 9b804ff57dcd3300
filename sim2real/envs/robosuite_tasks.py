"""The robosuite side of the backend: robot and controller checks, and a Reach task.

robosuite has no reach task, so ``Sim2RealReach`` is built the way robosuite builds its own tasks:
a ``ManipulationEnv`` with robosuite's table arena, plus a mocap target (a visual site) that is
re-sampled in the workspace at every reset, so no XML is recompiled. Success: the gripper's grip
site within 1 cm of the target.

Importing this module imports robosuite (about 1.5 s); ``sim2real.envs`` only names it in string
entry points, so ``import sim2real.envs`` stays light.
"""

from __future__ import annotations

import copy
import xml.etree.ElementTree as ET
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import numpy as np

from sim2real.errors import UnknownNameError
from sim2real.randomization.robosuite_compat import import_robosuite

robosuite = import_robosuite()

from robosuite.controllers import (  # noqa: E402  (after the quiet import)
    load_composite_controller_config,
    load_part_controller_config,
)
from robosuite.environments.manipulation.manipulation_env import ManipulationEnv  # noqa: E402
from robosuite.models.arenas import TableArena  # noqa: E402
from robosuite.models.robots.robot_model import REGISTERED_ROBOTS  # noqa: E402
from robosuite.models.tasks import ManipulationTask  # noqa: E402
from robosuite.robots import ROBOT_CLASS_MAPPING, FixedBaseRobot  # noqa: E402
from robosuite.utils.observables import Observable, sensor  # noqa: E402


# ---- controllers: arm part controllers that work in robosuite 1.5.2 ---------------------------
def _cartesian(n_rot: int) -> Callable[[int], tuple[str, ...]]:
    return lambda n_joints: ("m",) * 3 + ("rad",) * n_rot


# Controller → physical unit of each arm command dimension (given the number of arm joints).
# Left out on purpose: JOINT_VELOCITY raises AttributeError in its constructor in robosuite 1.5.2
# (it sets the read-only property ``torque_compensation``), and IK_POSE needs pybullet.
CONTROLLER_UNITS: dict[str, Callable[[int], tuple[str, ...]]] = {
    "OSC_POSE": _cartesian(3),
    "OSC_POSITION": _cartesian(0),
    "JOINT_POSITION": lambda n: ("rad",) * n,
    "JOINT_TORQUE": lambda n: ("N*m",) * n,
}


def check_controller(name: str) -> str:
    if name not in CONTROLLER_UNITS:
        raise UnknownNameError("robosuite controller", name, CONTROLLER_UNITS)
    return name


def _is_single_arm(name: str) -> bool:
    """A fixed-base robot with one arm: the kind these tasks can seat at a table."""
    cls = ROBOT_CLASS_MAPPING.get(name)
    return (
        cls is not None
        and name in REGISTERED_ROBOTS
        and issubclass(cls, FixedBaseRobot)
        and REGISTERED_ROBOTS[name]().arm_type == "single"
    )


def single_arm_robots() -> list[str]:
    return sorted(n for n in ROBOT_CLASS_MAPPING if _is_single_arm(n))


def check_robot(name: str) -> str:
    if not _is_single_arm(name):
        raise UnknownNameError("robosuite robot", name, single_arm_robots())
    return name


def controller_config(robot: str, controller: str) -> dict[str, Any]:
    """The robot's default composite config with its arm part controller swapped for ours."""
    config: dict[str, Any] = load_composite_controller_config(robot=robot)
    arm = config["body_parts"]["right"]
    if arm["type"] != controller:
        part = load_part_controller_config(default_controller=controller)
        part["gripper"] = copy.deepcopy(arm.get("gripper", {"type": "GRIP"}))
        config["body_parts"]["right"] = part
    return config


# ---- Reach: a robosuite task of our own ------------------------------------------------------
TARGET_BODY = "sim2real_target"
TARGET_SITE = "sim2real_target_site"


class Sim2RealReach(ManipulationEnv):
    """Bring the gripper's grip site within ``success_m`` of a target sampled above the table.

    The target box is relative to the table-top centre, in the world frame (the robot sits at the
    table edge at -x, as in robosuite's Lift); every single-arm robosuite robot reaches all of it.
    """

    def __init__(
        self,
        robots: Any,
        table_full_size: tuple[float, float, float] = (0.8, 0.8, 0.05),
        target_low_m: tuple[float, float, float] = (-0.20, -0.25, 0.05),
        target_high_m: tuple[float, float, float] = (0.15, 0.25, 0.30),
        success_m: float = 0.01,
        reward_shaping: bool = True,
        initialization_noise: Any = "default",
        **kwargs: Any,
    ) -> None:
        self.table_full_size = table_full_size
        self.table_offset = np.array((0.0, 0.0, 0.8))
        self.target_low_m = np.asarray(target_low_m, dtype=float)
        self.target_high_m = np.asarray(target_high_m, dtype=float)
        self.success_m = success_m
        self.reward_shaping = reward_shaping
        super().__init__(robots=robots, initialization_noise=initialization_noise, **kwargs)

    # robosuite hooks ---------------------------------------------------------------------------
    def _load_model(self) -> None:
        super()._load_model()
        robot_model = self.robots[0].robot_model
        robot_model.set_base_xpos(robot_model.base_xpos_offset["table"](self.table_full_size[0]))
        arena = TableArena(table_full_size=self.table_full_size, table_offset=self.table_offset)
        arena.set_origin([0, 0, 0])
        self.model = ManipulationTask(
            mujoco_arena=arena, mujoco_robots=[r.robot_model for r in self.robots]
        )
        centre = self.table_offset + (self.target_low_m + self.target_high_m) / 2
        body = ET.Element(
            "body", name=TARGET_BODY, mocap="true", pos=" ".join(f"{v:g}" for v in centre)
        )
        ET.SubElement(
            body,
            "site",
            name=TARGET_SITE,
            type="sphere",
            size="0.015",
            rgba="0.1 0.8 0.1 0.8",
        )
        self.model.worldbody.append(body)

    def _setup_references(self) -> None:
        super()._setup_references()
        m = self.sim.model
        self.target_mocap_id = int(m.body_mocapid[m.body_name2id(TARGET_BODY)])
        self.grip_site_id = int(self.robots[0].eef_site_id["right"])

    def _setup_observables(self) -> OrderedDict[str, Any]:
        observables: OrderedDict[str, Any] = super()._setup_observables()

        @sensor(modality="object")
        def target_pos(obs_cache: dict[str, Any]) -> np.ndarray:
            return self.target_position().copy()

        @sensor(modality="object")
        def gripper_to_target_pos(obs_cache: dict[str, Any]) -> np.ndarray:
            return self.target_position() - self.grip_position()

        for s in (target_pos, gripper_to_target_pos):
            observables[s.__name__] = Observable(
                name=s.__name__, sensor=s, sampling_rate=self.control_freq
            )
        return observables

    def _reset_internal(self) -> None:
        super()._reset_internal()
        if not self.deterministic_reset:
            offset = self.rng.uniform(self.target_low_m, self.target_high_m)
            self.sim.data.mocap_pos[self.target_mocap_id] = self.table_offset + offset

    def reward(self, action: Any = None) -> float:
        """1 on success; else, when shaped, 1 - tanh(10 d) as robosuite's reaching terms."""
        d = self.target_distance()
        if d < self.success_m:
            return 1.0
        return float(1.0 - np.tanh(10.0 * d)) if self.reward_shaping else 0.0

    def _check_success(self) -> bool:
        return self.target_distance() < self.success_m

    # helpers ------------------------------------------------------------------------------------
    def target_position(self) -> np.ndarray:
        """(3,) world frame."""
        return np.asarray(self.sim.data.mocap_pos[self.target_mocap_id])

    def grip_position(self) -> np.ndarray:
        """(3,) world frame."""
        return np.asarray(self.sim.data.site_xpos[self.grip_site_id])

    def target_distance(self) -> float:
        return float(np.linalg.norm(self.target_position() - self.grip_position()))


__all__ = [
    "CONTROLLER_UNITS",
    "TARGET_BODY",
    "TARGET_SITE",
    "Sim2RealReach",
    "check_controller",
    "check_robot",
    "controller_config",
    "robosuite",
    "single_arm_robots",
]
