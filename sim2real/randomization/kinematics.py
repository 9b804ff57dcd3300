"""Kinematics DR: link lengths, joint zero offsets and the tool offset of the MuJoCo arm.

The policy's spec is what the user believes; a real arm is printed a few millimetres off and has
a horn a little off zero (issue 20: links 3-4 mm off broke a policy that shrugged off slow,
laggy servos). So MuJoCo gets the randomised geometry while the observation's forward-kinematics
features (``sim2real.observation``) keep the spec: the policy learns to act on a belief that is
slightly wrong, as on the real arm.

Joint offsets follow ``hardware.plant``'s convention, **physical = reading + offset**: qpos stays
the servo's reading (what the actuator drives and the sensor reports), and the child body's frame
is turned by the offset about the joint axis, so the link sits ``offset`` from what the servo
reads. The wrist body is turned back by the pitch offsets, so the parallel linkage still keeps the
gripper level (its tendon acts on the readings).

Parameters (per episode, independent draws):
  ``link_length_delta_m`` (3,): base height, upper arm, forearm, added to the spec's lengths;
  ``joint_offset_rad`` (3,): base yaw, shoulder, elbow;
  ``tool_offset_delta_m`` (2,): tool forward, tool down, added to the spec's tool offsets.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Mapping
from dataclasses import dataclass

import mujoco
import numpy as np

from sim2real import model as names
from sim2real.randomization.base import ModelIds, ModelSnapshot, Params
from sim2real.randomization.config import Range

# Bodies whose parent-frame position is a link length: base height moves the upper arm's origin
# (+z of the turret), the upper arm moves the forearm's (+z), the forearm moves the wrist's (+x).
_LINK_BODIES = ("upper_arm", "forearm", "wrist")
_LINK_AXES = (2, 2, 0)
# The geoms drawn along each link (their visual/collision length follows it) and their axis in the
# geom's own frame (capsules: z; the turret box: z).
_LINK_GEOMS = ("turret", "upper_arm", "forearm")
_JOINT_BODIES = ("turret", "upper_arm", "forearm")
_WRIST_AXIS = np.array([0.0, 1.0, 0.0])  # the passive wrist_level hinge


@dataclass(frozen=True)
class _Ids:
    link_bodies: np.ndarray  # (3,)
    link_geoms: np.ndarray  # (3,)
    joint_bodies: np.ndarray  # (3,)
    joint_axes: np.ndarray  # (3, 3) joint axis in its body frame
    pitch_signs: np.ndarray  # (2,) tendon coefficients of shoulder and elbow
    wrist_body: int
    tool_site: int
    tool_bodies: np.ndarray  # finger bodies (absent without a gripper)
    palm_geom: int  # -1 without a gripper
    wrist_geom: int

    @classmethod
    def of(cls, model: mujoco.MjModel, ids: ModelIds) -> _Ids:
        jnts = model.dof_jntid[ids.arm_dofs]
        tendon = model.tendon(names.LEVEL_TENDON).id
        adr, num = model.tendon_adr[tendon], model.tendon_num[tendon]
        coef = {int(model.wrap_objid[k]): float(model.wrap_prm[k]) for k in range(adr, adr + num)}
        fingers = [
            mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, n) for n in names.FINGER_JOINTS
        ]
        return cls(
            link_bodies=np.array([model.body(n).id for n in _LINK_BODIES], dtype=np.intp),
            link_geoms=np.array([model.geom(n).id for n in _LINK_GEOMS], dtype=np.intp),
            joint_bodies=np.array([model.body(n).id for n in _JOINT_BODIES], dtype=np.intp),
            joint_axes=model.jnt_axis[jnts].copy(),
            pitch_signs=np.array([coef[int(jnts[1])], coef[int(jnts[2])]]),
            wrist_body=model.body("wrist").id,
            tool_site=model.site(names.TOOL_SITE).id,
            tool_bodies=np.array([b for b in fingers if b >= 0], dtype=np.intp),
            palm_geom=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "palm"),
            wrist_geom=model.geom("wrist").id,
        )


# Ids resolved once per model (a reset applies DR every episode); None: no arm3 linkage.
_IDS: weakref.WeakKeyDictionary[mujoco.MjModel, _Ids | None] = weakref.WeakKeyDictionary()


def _ids_of(model: mujoco.MjModel, ids: ModelIds) -> _Ids | None:
    if model not in _IDS:
        tendon = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TENDON, names.LEVEL_TENDON)
        _IDS[model] = None if tendon < 0 else _Ids.of(model, ids)
    return _IDS[model]


def _norm(v: np.ndarray) -> float:
    """``np.linalg.norm`` of a vector, the same bits (it is sqrt(v·v)) without its overhead."""
    return math.sqrt(float(v.dot(v)))


def sample(rng: np.random.Generator, ranges: Mapping[str, Range], ids: ModelIds) -> Params:
    """Independent draws per link, per joint and per tool axis."""
    n = len(ids.arm_dofs)
    return {
        "link_length_delta_m": ranges["link_length_delta_m"].sample(rng, 3),
        "joint_offset_rad": ranges["joint_offset_rad"].sample(rng, n),
        "tool_offset_delta_m": ranges["tool_offset_delta_m"].sample(rng, 2),
    }


def _turn(quat: np.ndarray, axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """``quat`` followed by a rotation of ``angle_rad`` about ``axis`` (in the body frame)."""
    turn = np.zeros(4)
    mujoco.mju_axisAngle2Quat(turn, np.asarray(axis, dtype=float), float(angle_rad))
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, np.asarray(quat, dtype=float), turn)
    return out


def _lengthen(
    model: mujoco.MjModel, nominal: ModelSnapshot, geom: int, along: int, delta_m: float
) -> None:
    """A geom drawn from its body's origin along ``along`` (local index of its length axis)
    grows by ``delta_m`` at the far end: centre moves by half, half-length grows by half."""
    half = 0.5 * delta_m
    centre = nominal["geom_pos"][geom]
    direction = centre / _norm(centre)
    model.geom_pos[geom] = centre + direction * half
    size = nominal["geom_size"][geom].copy()
    size[along] += half
    model.geom_size[geom] = size
    capsule = model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_CAPSULE
    model.geom_rbound[geom] = size[0] + size[1] if capsule else _norm(size)
    aabb = nominal["geom_aabb"][geom].copy()
    aabb[3 + 2 if along == 1 else 3 + along] += half  # capsule length (size[1]) is its local z
    model.geom_aabb[geom] = aabb


def apply(model: mujoco.MjModel, nominal: ModelSnapshot, ids: ModelIds, params: Params) -> None:
    """Write nominal + deltas (never compounds); the caller restored nominal before. A model
    without the arm3 twin's linkage (the Kuka grasp scene) has no hobby-arm geometry to vary."""
    k = _ids_of(model, ids)
    if k is None:
        return
    links = np.asarray(params["link_length_delta_m"], dtype=float)
    offsets = np.asarray(params["joint_offset_rad"], dtype=float)
    tool = np.asarray(params["tool_offset_delta_m"], dtype=float)

    for body, axis, delta in zip(k.link_bodies, _LINK_AXES, links, strict=True):
        model.body_pos[body, axis] = nominal["body_pos"][body, axis] + delta
    # geoms and centres of mass along the links: turret box (half-size z), capsules (size[1])
    for geom, along, delta in zip(k.link_geoms, (2, 1, 1), links, strict=True):
        _lengthen(model, nominal, int(geom), along, float(delta))
    for body, delta in zip(k.joint_bodies, links, strict=True):
        ipos = nominal["body_ipos"][body]
        norm = _norm(ipos)
        if norm > 0:
            model.body_ipos[body] = ipos + ipos / norm * 0.5 * delta

    for body, axis, offset in zip(k.joint_bodies, k.joint_axes, offsets, strict=True):
        model.body_quat[body] = _turn(nominal["body_quat"][body], axis, offset)
    # level gripper: the wrist undoes the pitch offsets its tendon cannot see
    level = -float(k.pitch_signs @ offsets[1:3])
    model.body_quat[k.wrist_body] = _turn(nominal["body_quat"][k.wrist_body], _WRIST_AXIS, level)

    shift = np.array([tool[0], 0.0, -tool[1]])  # forward is +x, down is -z of the level wrist
    model.site_pos[k.tool_site] = nominal["site_pos"][k.tool_site] + shift
    for body in k.tool_bodies:
        model.body_pos[body] = nominal["body_pos"][body] + shift
    if k.palm_geom >= 0:
        model.geom_pos[k.palm_geom] = nominal["geom_pos"][k.palm_geom] + shift
    _lengthen(model, nominal, k.wrist_geom, 0, float(tool[0]))
