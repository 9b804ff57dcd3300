"""Forward-kinematics perception: an arm on a serial bus with no cameras (``--perception fk``).

The tool is where the spec's forward kinematics puts it for the servo readings; the task's
objects are where the contract placed them for the episode (``KinematicWorld``: a person sets a
target plate there, the log says where, or it is a goal the arm is sent to). Nothing here sees
the world, so nothing knows the truth: success is judged on these estimates, as on a real arm
with cameras. It is the deploy profile's perception for checking an arm and a policy end to end
on a computer without cameras, and it imports neither MuJoCo nor OpenCV.
"""

from __future__ import annotations

import contextlib
import logging
from typing import TYPE_CHECKING

import numpy as np

from hardware.arm import ArmBase, ArmState
from hardware.spec import ArmSpec
from sim2real.envs.contract import ObjectEstimate, Percept, View

if TYPE_CHECKING:
    from sim2real.deploy.policy_io import PolicyIO
    from sim2real.deploy.runner import DeployOptions

log = logging.getLogger(__name__)


class KinematicWorld:
    """The episode's objects as placed by the contract; no truth (a real arm)."""

    places_objects = False  # a person (or nobody, for a virtual goal) puts them there

    def __init__(self) -> None:
        self.objects_m: dict[str, np.ndarray] = {}

    def new_episode(self, placement: dict[str, np.ndarray]) -> None:
        """Keep the placed positions (a pose's first three numbers) for perception."""
        self.objects_m = {
            name: np.asarray(pose, dtype=float).reshape(-1)[:3].copy()
            for name, pose in placement.items()
        }
        where = ", ".join(f"{n} at {np.round(p, 3).tolist()} m" for n, p in self.objects_m.items())
        log.info("episode objects (base frame): %s", where)

    def clear(self) -> None:
        """Nothing on the table to take away."""

    def view(self, actuators_rad: np.ndarray, commanded_rad: np.ndarray | None) -> View | None:
        return None

    def close(self) -> None:
        """Nothing to release."""


class KinematicPerception:
    """Tool from the readings through the spec's kinematics; objects from the world."""

    def __init__(self, spec: ArmSpec, world: KinematicWorld) -> None:
        self.spec, self.world = spec, world

    def reset(self) -> None:
        """Stateless: the world holds the episode's objects."""

    def perceive(self, state: ArmState, command_s: float) -> Percept:
        q_rad = np.asarray(state.positions_rad[: self.spec.n_joints], dtype=float)
        objects = {n: ObjectEstimate(p.copy(), 0.0) for n, p in self.world.objects_m.items()}
        return Percept(self.spec.forward_kinematics(q_rad), objects)

    def close(self) -> None:
        """Nothing to release."""


def build_serial_fk(
    spec: ArmSpec, io: PolicyIO, opts: DeployOptions, stack: contextlib.ExitStack
) -> tuple[ArmBase, KinematicPerception, KinematicWorld]:
    """``--backend serial --perception fk``: the bus, and kinematics in place of cameras."""
    from hardware.serial_arm import SerialArm
    from sim2real.deploy.runner import check_device_readings

    assert opts.port is not None  # DeployOptions checks it
    arm = SerialArm(spec, opts.port, opts.protocol, opts.baud, opts.joint_calibration)
    stack.enter_context(arm)
    check_device_readings(arm, spec)
    world = KinematicWorld()
    return arm, KinematicPerception(spec, world), world
