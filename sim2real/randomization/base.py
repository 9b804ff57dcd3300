"""What DR touches in a model, resolved once, and an exact snapshot of its nominal values."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from sim2real import model as names
from sim2real.noise import NoiseBuffer

# One category's sampled parameters (key -> value): what ``sample`` returns and ``apply`` takes.
# The one alias for it: every DR module imports this.
Params = dict[str, Any]

__all__ = ["ModelIds", "ModelSnapshot", "NoiseBuffer", "Params"]  # NoiseBuffer: sensing.py

# Every MjModel field any DR category writes. restore() copies exactly these back.
TOUCHED_FIELDS: tuple[str, ...] = (
    "body_mass",
    "body_inertia",
    "dof_damping",
    "dof_frictionloss",
    "dof_armature",
    "actuator_gainprm",
    "actuator_biasprm",
    "light_diffuse",
    "light_pos",
    "geom_rgba",
    "mat_rgba",
    "cam_pos",
    "cam_fovy",
    "geom_size",
    "geom_rbound",
    "geom_aabb",
    "geom_friction",
    "body_pos",
    "body_quat",
    "body_ipos",
    "site_pos",
    "geom_pos",
)


@dataclass(frozen=True)
class ModelIds:
    """Ids DR and the envs need, looked up by name once per model."""

    arm_bodies: np.ndarray  # bodies whose mass the dynamics layer scales
    arm_dofs: np.ndarray  # servo-driven dofs (base yaw, shoulder, elbow)
    servo_actuators: np.ndarray  # actuators of the joints (not the gripper)
    colour_geoms: np.ndarray
    cube_geom: int  # -1 when the scene has no cube
    cube_body: int
    cameras: np.ndarray
    lights: np.ndarray

    @classmethod
    def from_model(cls, model: mujoco.MjModel, joint_names: Iterable[str]) -> ModelIds:
        joints = list(joint_names)
        dofs = np.array([model.joint(n).dofadr[0] for n in joints], dtype=np.intp)
        bodies = np.array(
            [model.body(n).id for n in ("turret", "upper_arm", "forearm", "wrist")],
            dtype=np.intp,
        )
        acts = np.array([model.actuator(n).id for n in joints], dtype=np.intp)
        colour = [
            model.geom(n).id
            for n in ("upper_arm", "forearm", "wrist", names.TABLE_GEOM, names.MARKER_GEOM)
        ]
        cube_geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, names.CUBE_GEOM)
        cube_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, names.CUBE_BODY)
        if cube_geom >= 0:
            colour.append(cube_geom)
        return cls(
            arm_bodies=bodies,
            arm_dofs=dofs,
            servo_actuators=acts,
            colour_geoms=np.array(colour, dtype=np.intp),
            cube_geom=int(cube_geom),
            cube_body=int(cube_body),
            cameras=np.arange(model.ncam, dtype=np.intp),
            lights=np.arange(model.nlight, dtype=np.intp),
        )


class ModelSnapshot:
    """Copies of the nominal values of ``TOUCHED_FIELDS``; ``restore`` is bit-exact."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self._model = model
        self.values: dict[str, np.ndarray] = {f: getattr(model, f).copy() for f in TOUCHED_FIELDS}
        # MjModel's arrays are views of its buffers, valid while the model lives: fetched once
        # (a reset restores every episode, and each attribute fetch builds a new array object)
        self._pairs = [(getattr(model, f), v) for f, v in self.values.items()]

    def __getitem__(self, field: str) -> np.ndarray:
        return self.values[field]

    def restore(self) -> None:
        for view, value in self._pairs:
            np.copyto(view, value)
