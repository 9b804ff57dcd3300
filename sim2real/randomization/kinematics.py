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
from typing import Any

import mujoco
import numpy as np

from sim2real import model as names
from sim2real.randomization.base import (
    DirectKey,
    ModelIds,
    ModelSnapshot,
    Params,
    PlanCache,
    draw_keys,
)
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
_ROWS = np.arange(4)  # the lengthened geoms (``_Plan.geoms``)


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
    return draw_keys(direct_keys(ids), rng, ranges)


def direct_keys(ids: ModelIds) -> list[DirectKey]:
    """Each draw, in order, with its size: per link, per joint and per tool axis."""
    return [
        ("link_length_delta_m", 3, None),
        ("joint_offset_rad", len(ids.arm_dofs), None),
        ("tool_offset_delta_m", 2, None),
    ]


@dataclass(frozen=True)
class _Plan:
    """What ``apply`` writes, with every term that depends on the nominal model alone worked out
    once: a reset applies DR every episode, and this is most of its cost otherwise. The
    per-episode arithmetic is the same operations on the same values, so the same bits."""

    geoms: np.ndarray  # (4,) lengthened geoms: the three links', then the wrist's (tool forward)
    along: np.ndarray  # (4,) local index of each one's length axis
    aabb_at: np.ndarray  # (4,) its aabb half-length entry
    box_rows: tuple[int, ...]  # rows whose bounding radius is |size| (not a capsule's)
    centre: np.ndarray  # (4, 3) nominal geom_pos
    direction: np.ndarray  # (4, 3) centre / |centre|
    size: np.ndarray  # (4, 3) nominal geom_size
    aabb: np.ndarray  # (4, 6) nominal geom_aabb
    link_pos: np.ndarray  # (3,) nominal body_pos of the link bodies along their axes
    ipos_rows: np.ndarray  # joint bodies with a centre of mass off their origin
    ipos: np.ndarray  # (m, 3) their nominal body_ipos
    ipos_half_unit: np.ndarray  # (m, 3) ipos / |ipos| * 0.5
    quats: np.ndarray  # (4, 4) nominal body_quat: the joint bodies, then the wrist
    axes: np.ndarray  # (4, 3) the joint axes, then the wrist's
    site_pos: np.ndarray  # (3,) nominal tool site
    tool_body_pos: np.ndarray  # (t, 3) nominal finger bodies
    palm_pos: np.ndarray  # (3,) nominal palm geom (unused without a gripper)

    @classmethod
    def of(cls, model: mujoco.MjModel, nominal: ModelSnapshot, k: _Ids) -> _Plan:
        geoms = np.append(k.link_geoms, k.wrist_geom)
        along = np.array([2, 1, 1, 0])
        centre = nominal["geom_pos"][geoms]
        norms = np.array([_norm(c) for c in centre])
        jb = k.joint_bodies
        ipos = nominal["body_ipos"][jb]
        ipos_norm = np.array([_norm(v) for v in ipos])
        rows = np.flatnonzero(ipos_norm > 0)
        capsule = model.geom_type[geoms] == mujoco.mjtGeom.mjGEOM_CAPSULE
        return cls(
            geoms=geoms,
            along=along,
            aabb_at=np.where(along == 1, 3 + 2, 3 + along),  # capsule length is its local z
            box_rows=tuple(int(i) for i in np.flatnonzero(~capsule)),
            centre=centre,
            direction=centre / norms[:, None],
            size=nominal["geom_size"][geoms],
            aabb=nominal["geom_aabb"][geoms],
            link_pos=nominal["body_pos"][k.link_bodies, _LINK_AXES],
            ipos_rows=rows,
            ipos=ipos[rows],
            ipos_half_unit=ipos[rows] / ipos_norm[rows, None] * 0.5,
            quats=nominal["body_quat"][np.append(jb, k.wrist_body)],
            axes=np.vstack([k.joint_axes, _WRIST_AXIS]),
            site_pos=nominal["site_pos"][k.tool_site],
            tool_body_pos=nominal["body_pos"][k.tool_bodies],
            palm_pos=nominal["geom_pos"][max(k.palm_geom, 0)],
        )


_PLANS: weakref.WeakKeyDictionary[ModelSnapshot, _Plan] = weakref.WeakKeyDictionary()


def apply_reference(
    model: mujoco.MjModel, nominal: ModelSnapshot, ids: ModelIds, params: Params
) -> None:
    """Write nominal + deltas (never compounds); the caller restored nominal before. A model
    without the arm3 twin's linkage (the Kuka grasp scene) has no hobby-arm geometry to vary.

    Links lengthen at their far end: the next body moves along the link, the link's geoms'
    centres move by half (their half-lengths, bounding radii and boxes grow by half), and the
    centres of mass move by half along their offset. Joint bodies turn by their offsets; the
    wrist turns back by the pitch offsets; the tool (site, fingers, palm) shifts."""
    k = _ids_of(model, ids)
    if k is None:
        return
    p = _PLANS.get(nominal)
    if p is None:
        p = _PLANS[nominal] = _Plan.of(model, nominal, k)
    links = np.asarray(params["link_length_delta_m"], dtype=float)
    offsets = np.asarray(params["joint_offset_rad"], dtype=float)
    tool = np.asarray(params["tool_offset_delta_m"], dtype=float)

    model.body_pos[k.link_bodies, _LINK_AXES] = p.link_pos + links
    half = 0.5 * np.append(links, tool[0])  # the three links, then the wrist by tool forward
    model.geom_pos[p.geoms] = p.centre + p.direction * half[:, None]
    size = p.size.copy()
    size[_ROWS, p.along] += half
    model.geom_size[p.geoms] = size
    rbound = size[:, 0] + size[:, 1]
    for i in p.box_rows:
        rbound[i] = _norm(size[i])
    model.geom_rbound[p.geoms] = rbound
    aabb = p.aabb.copy()
    aabb[_ROWS, p.aabb_at] += half
    model.geom_aabb[p.geoms] = aabb
    if len(p.ipos_rows):
        rows = p.ipos_rows
        model.body_ipos[k.joint_bodies[rows]] = p.ipos + p.ipos_half_unit * links[rows, None]

    # level gripper: the wrist undoes the pitch offsets its tendon cannot see
    level = -float(k.pitch_signs @ offsets[1:3])
    bodies = np.append(k.joint_bodies, k.wrist_body)
    quat = model.body_quat
    turn = np.zeros(4)
    for i, angle in enumerate((*offsets.tolist(), level)):
        mujoco.mju_axisAngle2Quat(turn, p.axes[i], angle)
        mujoco.mju_mulQuat(quat[bodies[i]], p.quats[i], turn)

    shift = np.array([tool[0], 0.0, -tool[1]])  # forward is +x, down is -z of the level wrist
    model.site_pos[k.tool_site] = p.site_pos + shift
    if len(k.tool_bodies):
        model.body_pos[k.tool_bodies] = p.tool_body_pos + shift
    if k.palm_geom >= 0:
        model.geom_pos[k.palm_geom] = p.palm_pos + shift


_KERNEL: list[Any] = []  # the compiled ``_write_geometry``, made on first use


def _compiled() -> Any:
    """numba is imported here, not with the module: ``from sim2real.randomization import
    DRConfig`` (the CLI, evaluation) stays light; the kernel loads from numba's disk cache."""
    if not _KERNEL:
        import numba

        try:
            _KERNEL.append(numba.njit(cache=True)(_write_geometry))
        except RuntimeError:  # no writable cache directory: compile in this process
            _KERNEL.append(numba.njit(cache=False)(_write_geometry))
    return _KERNEL[0]


def _write_geometry(
    links: np.ndarray,
    tool: np.ndarray,
    link_bodies: np.ndarray,
    link_axes: np.ndarray,
    link_pos: np.ndarray,
    geoms: np.ndarray,
    centre: np.ndarray,
    direction: np.ndarray,
    size0: np.ndarray,
    along: np.ndarray,
    aabb0: np.ndarray,
    aabb_at: np.ndarray,
    ipos_bodies: np.ndarray,
    ipos_rows: np.ndarray,
    ipos0: np.ndarray,
    ipos_half_unit: np.ndarray,
    site: int,
    site_pos0: np.ndarray,
    tool_bodies: np.ndarray,
    tool_body_pos0: np.ndarray,
    palm_geom: int,
    palm_pos0: np.ndarray,
    body_pos: np.ndarray,
    geom_pos: np.ndarray,
    geom_size: np.ndarray,
    geom_rbound: np.ndarray,
    geom_aabb: np.ndarray,
    body_ipos: np.ndarray,
    site_pos: np.ndarray,
) -> None:
    """``apply_reference``'s element operations in its order, one call (each is a single
    IEEE add or multiply, so the bits are numpy's), but the boxes' bounding radii (a BLAS
    dot) and the quaternions (MuJoCo's own functions), which stay with the caller."""
    for i in range(3):
        body_pos[link_bodies[i], link_axes[i]] = link_pos[i] + links[i]
    half = np.empty(4)
    for i in range(3):
        half[i] = 0.5 * links[i]
    half[3] = 0.5 * tool[0]
    for j in range(4):
        g = geoms[j]
        for c in range(3):
            geom_pos[g, c] = centre[j, c] + direction[j, c] * half[j]
            geom_size[g, c] = size0[j, c]
        geom_size[g, along[j]] += half[j]
        geom_rbound[g] = geom_size[g, 0] + geom_size[g, 1]
        for c in range(6):
            geom_aabb[g, c] = aabb0[j, c]
        geom_aabb[g, aabb_at[j]] += half[j]
    for m in range(len(ipos_bodies)):
        for c in range(3):
            body_ipos[ipos_bodies[m], c] = ipos0[m, c] + ipos_half_unit[m, c] * links[ipos_rows[m]]
    shift = np.empty(3)
    shift[0], shift[1], shift[2] = tool[0], 0.0, -tool[1]
    for c in range(3):
        site_pos[site, c] = site_pos0[c] + shift[c]
    for t in range(len(tool_bodies)):
        for c in range(3):
            body_pos[tool_bodies[t], c] = tool_body_pos0[t, c] + shift[c]
    if palm_geom >= 0:
        for c in range(3):
            geom_pos[palm_geom, c] = palm_pos0[c] + shift[c]


@dataclass(frozen=True)
class _Views:
    """``apply_reference``'s lookups done once per model: the ids, the plan, the model's arrays
    (views of its buffers) and the rows the quaternion calls write and read."""

    k: _Ids
    p: _Plan
    write: Any  # the compiled ``_write_geometry``
    geometry: tuple[Any, ...]  # its arguments after the parameters
    box_geoms: tuple[int, ...]  # geoms whose bounding radius is |size|
    quat_out: tuple[np.ndarray, ...]  # body_quat rows: the joint bodies, then the wrist
    quat_in: tuple[np.ndarray, ...]  # their nominal rows
    axes: tuple[np.ndarray, ...]
    turn: np.ndarray  # scratch (4,)
    geom_size: np.ndarray
    geom_rbound: np.ndarray

    @classmethod
    def of(cls, model: mujoco.MjModel, nominal: ModelSnapshot, ids: ModelIds) -> _Views | None:
        k = _ids_of(model, ids)
        if k is None:
            return None
        p = _PLANS.get(nominal)
        if p is None:
            p = _PLANS[nominal] = _Plan.of(model, nominal, k)
        bodies = np.append(k.joint_bodies, k.wrist_body)
        quat = model.body_quat
        i64 = np.int64
        geometry = (
            k.link_bodies.astype(i64),
            np.array(_LINK_AXES, dtype=i64),
            np.ascontiguousarray(p.link_pos, dtype=float),
            p.geoms.astype(i64),
            p.centre,
            p.direction,
            p.size,
            p.along.astype(i64),
            p.aabb,
            p.aabb_at.astype(i64),
            k.joint_bodies[p.ipos_rows].astype(i64),
            p.ipos_rows.astype(i64),
            p.ipos.reshape(-1, 3),
            p.ipos_half_unit.reshape(-1, 3),
            int(k.tool_site),
            p.site_pos,
            k.tool_bodies.astype(i64),
            p.tool_body_pos.reshape(-1, 3),
            int(k.palm_geom),
            p.palm_pos,
            model.body_pos,
            model.geom_pos,
            model.geom_size,
            model.geom_rbound,
            model.geom_aabb,
            model.body_ipos,
            model.site_pos,
        )
        return cls(
            k=k,
            p=p,
            write=_compiled(),
            geometry=geometry,
            box_geoms=tuple(int(p.geoms[i]) for i in p.box_rows),
            quat_out=tuple(quat[b] for b in bodies),
            quat_in=tuple(p.quats[i] for i in range(len(bodies))),
            axes=tuple(p.axes[i] for i in range(len(bodies))),
            turn=np.zeros(4),
            geom_size=model.geom_size,
            geom_rbound=model.geom_rbound,
        )


_VIEWS = PlanCache(_Views.of)


def apply(model: mujoco.MjModel, nominal: ModelSnapshot, ids: ModelIds, params: Params) -> None:
    """``apply_reference``'s operations on the same values (the same bits): the geometry in one
    compiled call through views resolved once per model, the quaternions by MuJoCo's functions
    as there (``tests/sim2real/randomization/test_appliers.py``)."""
    v = _VIEWS.get(model, nominal, ids)
    if v is None:
        return
    offsets = np.asarray(params["joint_offset_rad"], dtype=float)
    v.write(
        np.asarray(params["link_length_delta_m"], dtype=float),
        np.asarray(params["tool_offset_delta_m"], dtype=float),
        *v.geometry,
    )
    for g in v.box_geoms:
        v.geom_rbound[g] = _norm(v.geom_size[g])

    # level gripper: the wrist undoes the pitch offsets its tendon cannot see
    level = -float(v.k.pitch_signs @ offsets[1:3])
    turn = v.turn
    for out, nominal_quat, axis, angle in zip(
        v.quat_out, v.quat_in, v.axes, (*offsets.tolist(), level), strict=True
    ):
        mujoco.mju_axisAngle2Quat(turn, axis, angle)
        mujoco.mju_mulQuat(out, nominal_quat, turn)
