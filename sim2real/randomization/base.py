"""What DR touches in a model, resolved once, and an exact snapshot of its nominal values."""

from __future__ import annotations

import weakref
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import mujoco
import numpy as np

from sim2real import model as names
from sim2real.noise import NoiseBuffer

# One category's sampled parameters (key -> value): what ``sample`` returns and ``apply`` takes.
# The one alias for it: every DR module imports this.
Params = dict[str, Any]

__all__ = [  # NoiseBuffer: sensing.py
    "DirectKey",
    "ModelIds",
    "ModelSnapshot",
    "NoiseBuffer",
    "Params",
    "PlanCache",
    "as_index",
    "draw_keys",
    "round_steps",
]

# A category's draw listed: (key, ``Range.sample`` size or None for a scalar, cast or None). The
# list is the category's ``sample`` (``draw_keys``) and what the replay matches to its recording.
DirectKey = tuple[str, int | None, Callable[[Any], Any] | None]


def round_steps(x: Any) -> int:
    """A drawn count of whole steps (latency, delay)."""
    return round(float(x))


def draw_keys(keys: Sequence[DirectKey], rng: Any, ranges: Mapping[str, Any]) -> Params:
    """Each key's ``Range.sample`` in the listed order, cast as listed."""
    out: Params = {}
    for key, size, cast in keys:
        value = ranges[key].sample(rng, size)
        out[key] = value if cast is None else cast(value)
    return out


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


# MuJoCo draws a geom in its material's rgba while the geom's own rgba is this default value.
DEFAULT_GEOM_RGBA = np.array([0.5, 0.5, 0.5, 1.0], dtype=np.float32)


def shown_rgba(
    model: mujoco.MjModel,
    geoms: np.ndarray,
    geom_rgba: np.ndarray | None = None,
    mat_rgba: np.ndarray | None = None,
) -> np.ndarray:
    """(k, 4) colour each geom is drawn in: its material's rgba while its own is the default.

    Colour DR must jitter *this*: a jittered geom rgba leaves the default, so MuJoCo stops using
    the material's colour, and a textured table whose material is white turned ~0.5 grey on every
    draw (reach-pixels frames 30 % darker than the nominal scene, never as bright; a student
    trained on them failed on the nominal scene, 2026-11-27). ``geom_rgba`` / ``mat_rgba``: the
    arrays to read (a nominal snapshot's), the model's own by default."""
    g = model.geom_rgba if geom_rgba is None else geom_rgba
    m = model.mat_rgba if mat_rgba is None else mat_rgba
    rgba = np.array(g[geoms], dtype=g.dtype)
    mat = model.geom_matid[geoms]
    use_mat = (mat >= 0) & np.all(rgba == DEFAULT_GEOM_RGBA, axis=1)
    rgba[use_mat] = m[mat[use_mat]]
    return rgba


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


def as_index(ids: np.ndarray) -> slice | np.ndarray:
    """A run of consecutive ids as a slice (basic indexing: a view, cheaper to write through
    than a fancy index), other ids unchanged. The same elements either way."""
    ids = np.asarray(ids, dtype=np.intp)
    if len(ids) and np.array_equal(ids, np.arange(ids[0], ids[0] + len(ids))):
        return slice(int(ids[0]), int(ids[0]) + len(ids))
    return ids


T = TypeVar("T")


class PlanCache(Generic[T]):
    """An applier's per-model plan (ids as slices, nominal rows, model views), built once per
    snapshot: a reset applies DR every episode, and per-call lookups were most of its cost."""

    def __init__(self, build: Callable[[mujoco.MjModel, ModelSnapshot, ModelIds], T]) -> None:
        self._build = build
        self._plans: weakref.WeakKeyDictionary[
            ModelSnapshot, tuple[mujoco.MjModel, ModelIds, T]
        ] = weakref.WeakKeyDictionary()

    def get(self, model: mujoco.MjModel, nominal: ModelSnapshot, ids: ModelIds) -> T:
        entry = self._plans.get(nominal)
        if entry is None or entry[0] is not model or entry[1] is not ids:
            entry = self._plans[nominal] = (model, ids, self._build(model, nominal, ids))
        return entry[2]
