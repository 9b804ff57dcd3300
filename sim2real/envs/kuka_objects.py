"""The shipped set of diverse graspable objects, generated from a fixed seed (no downloads).

The seed project grasped random meshes from a downloaded PyBullet asset pack. Here the set is
generated procedurally (boxes, upright and lying cylinders, capsules, ellipsoids, composite L and
T shapes, every extent between 2 and 6 cm), so it is identical on every machine and ships as code.

Both Kuka twins load objects into fixed *slots* (free bodies with ``MAX_PARTS`` geoms each) by
rewriting geom type, size and pose and the body's mass properties in place: a new episode never
recompiles the model, and never rebuilds the renderer's GL context. Exact mass properties, bounding
spheres and boxes come from MuJoCo's own compiler, run once on a catalogue model of every object.
"""

from __future__ import annotations

import colorsys
import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from sim2real.errors import ConfigError, UnknownNameError

MAX_PARTS = 2  # an L or T shape is two boxes; every other family is one primitive
MIN_EXTENT_M = 0.02
MAX_EXTENT_M = 0.06
OBJECT_SET_SEED = 7  # the shipped set: change it and every study result changes
OBJECT_SET_SIZE = 100
# The seed project held out test objects; we keep the last 10% for that.
SPLITS: dict[str, slice] = {
    "train": slice(0, 90),
    "test": slice(90, OBJECT_SET_SIZE),
    "all": slice(0, OBJECT_SET_SIZE),
}
GEOM_TYPES: dict[str, int] = {
    "box": int(mujoco.mjtGeom.mjGEOM_BOX),
    "cylinder": int(mujoco.mjtGeom.mjGEOM_CYLINDER),
    "capsule": int(mujoco.mjtGeom.mjGEOM_CAPSULE),
    "ellipsoid": int(mujoco.mjtGeom.mjGEOM_ELLIPSOID),
    "sphere": int(mujoco.mjtGeom.mjGEOM_SPHERE),
}
_SIZE_COUNT = {"box": 3, "cylinder": 2, "capsule": 2, "ellipsoid": 3, "sphere": 1}
_LYING = (math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0)  # local z axis → world y
PARK_RADIUS_M = 0.01  # an unused slot is a small sphere resting on the floor, far off camera
PARK_MASS_KG = 0.01


@dataclass(frozen=True)
class Part:
    """One primitive of an object, in the object frame (MuJoCo size semantics)."""

    kind: str
    size_m: tuple[float, float, float]  # box: half sizes; cylinder/capsule: radius, half length
    pos_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if self.kind not in GEOM_TYPES:
            raise UnknownNameError("geom kind", self.kind, GEOM_TYPES)
        used = self.size_m[: _SIZE_COUNT[self.kind]]
        if not all(math.isfinite(s) and s > 0 for s in used):
            raise ConfigError(f"part {self.kind}: sizes {self.size_m} must be finite and > 0")

    def mjcf_size(self) -> str:
        return " ".join(f"{s:.6g}" for s in self.size_m[: _SIZE_COUNT[self.kind]])


@dataclass(frozen=True)
class ObjectSpec:
    """A graspable object; it rests on the plane ``z = -half_height_m`` of its own frame."""

    name: str
    family: str
    parts: tuple[Part, ...]
    rgba: tuple[float, float, float, float]
    density_kg_m3: float
    half_height_m: float
    half_extent_xy_m: tuple[float, float]

    def __post_init__(self) -> None:
        if not 1 <= len(self.parts) <= MAX_PARTS:
            raise ConfigError(f"object {self.name}: {len(self.parts)} parts, max {MAX_PARTS}")
        if not self.density_kg_m3 > 0:
            raise ConfigError(f"object {self.name}: density {self.density_kg_m3} must be > 0")

    @property
    def radius_xy_m(self) -> float:
        """Bounding-circle radius seen from above (for non-overlapping placement)."""
        return math.hypot(*self.half_extent_xy_m)

    @property
    def extents_m(self) -> tuple[float, float, float]:
        """Full bounding-box extents (x, y, z) in the resting pose."""
        hx, hy = self.half_extent_xy_m
        return (2 * hx, 2 * hy, 2 * self.half_height_m)


# ---- families: rng → (parts, half height, half extents xy) ---------------------------------------
Shape = tuple[tuple[Part, ...], float, tuple[float, float]]


def _extent(rng: np.random.Generator, high: float = MAX_EXTENT_M) -> float:
    return float(rng.uniform(MIN_EXTENT_M, high))


def _box(rng: np.random.Generator) -> Shape:
    ex, ey, ez = _extent(rng), _extent(rng), _extent(rng)
    return (Part("box", (ex / 2, ey / 2, ez / 2)),), ez / 2, (ex / 2, ey / 2)


def _cylinder(rng: np.random.Generator) -> Shape:
    d, h = _extent(rng), _extent(rng)
    return (Part("cylinder", (d / 2, h / 2, 0.0)),), h / 2, (d / 2, d / 2)


def _cylinder_lying(rng: np.random.Generator) -> Shape:
    d, length = _extent(rng, 0.05), _extent(rng)
    return (Part("cylinder", (d / 2, length / 2, 0.0), quat=_LYING),), d / 2, (d / 2, length / 2)


def _capsule(rng: np.random.Generator) -> Shape:
    d = _extent(rng, 0.04)
    length = float(rng.uniform(d + 0.005, MAX_EXTENT_M))  # tip to tip
    part = Part("capsule", (d / 2, (length - d) / 2, 0.0), quat=_LYING)
    return (part,), d / 2, (d / 2, length / 2)


def _ellipsoid(rng: np.random.Generator) -> Shape:
    ex, ey = _extent(rng), _extent(rng)
    ez = float(rng.uniform(MIN_EXTENT_M, min(ex, ey, 0.04)))  # flattest axis vertical: it rests
    return (Part("ellipsoid", (ex / 2, ey / 2, ez / 2)),), ez / 2, (ex / 2, ey / 2)


def _bars(
    rng: np.random.Generator, boxes: Callable[[float, float, float], list[tuple[float, ...]]]
) -> Shape:
    """Two bars of width ``t`` in an ``lx`` × ``ly`` footprint; ``boxes`` gives their extents
    (x0, x1, y0, y1) in footprint coordinates, re-centred here on the footprint centre."""
    t = float(rng.uniform(MIN_EXTENT_M, 0.03))
    lx, ly = float(rng.uniform(0.04, MAX_EXTENT_M)), float(rng.uniform(0.035, MAX_EXTENT_M))
    ez = float(rng.uniform(MIN_EXTENT_M, 0.04))
    parts = []
    for x0, x1, y0, y1 in boxes(t, lx, ly):
        centre = ((x0 + x1) / 2 - lx / 2, (y0 + y1) / 2 - ly / 2, 0.0)
        parts.append(Part("box", ((x1 - x0) / 2, (y1 - y0) / 2, ez / 2), pos_m=centre))
    return tuple(parts), ez / 2, (lx / 2, ly / 2)


def _l_shape(rng: np.random.Generator) -> Shape:
    return _bars(rng, lambda t, lx, ly: [(0.0, lx, 0.0, t), (0.0, t, t, ly)])


def _t_shape(rng: np.random.Generator) -> Shape:
    return _bars(
        rng,
        lambda t, lx, ly: [(0.0, lx, ly - t, ly), (lx / 2 - t / 2, lx / 2 + t / 2, 0.0, ly - t)],
    )


FAMILIES: dict[str, Callable[[np.random.Generator], Shape]] = {
    "box": _box,
    "cylinder": _cylinder,
    "cylinder_lying": _cylinder_lying,
    "capsule": _capsule,
    "ellipsoid": _ellipsoid,
    "l_shape": _l_shape,
    "t_shape": _t_shape,
}


def generate_object_set(seed: int, n: int) -> tuple[ObjectSpec, ...]:
    """``n`` objects cycling through the families (any 7 consecutive ones cover all of them)."""
    if n < 1:
        raise ConfigError(f"object set size {n} must be >= 1")
    rng = np.random.default_rng(seed)
    names = list(FAMILIES)
    out = []
    for i in range(n):
        family = names[i % len(names)]
        parts, half_h, half_xy = FAMILIES[family](rng)
        r, g, b = colorsys.hsv_to_rgb(
            float(rng.uniform()), float(rng.uniform(0.5, 0.9)), float(rng.uniform(0.6, 1.0))
        )
        out.append(
            ObjectSpec(
                name=f"{family}_{i:03d}",
                family=family,
                parts=parts,
                rgba=(r, g, b, 1.0),
                density_kg_m3=float(rng.uniform(300.0, 1200.0)),  # foam-filled PLA to rubber
                half_height_m=half_h,
                half_extent_xy_m=half_xy,
            )
        )
    return tuple(out)


@functools.lru_cache(maxsize=4)
def object_set(split: str = "all") -> tuple[ObjectSpec, ...]:
    """The shipped set (seed ``OBJECT_SET_SEED``), or its ``train`` / ``test`` split."""
    if split not in SPLITS:
        raise UnknownNameError("object split", split, SPLITS)
    return generate_object_set(OBJECT_SET_SEED, OBJECT_SET_SIZE)[SPLITS[split]]


# ---- catalogue: MuJoCo-compiled geometry and mass properties -------------------------------------
def _catalog_xml(objects: Sequence[ObjectSpec]) -> str:
    bodies = []
    for i, obj in enumerate(objects):
        geoms = "".join(
            f'<geom type="{p.kind}" size="{p.mjcf_size()}" '
            f'pos="{" ".join(f"{v:.6g}" for v in p.pos_m)}" '
            f'quat="{" ".join(f"{v:.6g}" for v in p.quat)}" density="{obj.density_kg_m3:.6g}"/>'
            for p in obj.parts
        )
        bodies.append(f'<body name="o{i}" pos="{i} 0 0"><freejoint/>{geoms}</body>')
    return f"<mujoco><worldbody>{''.join(bodies)}</worldbody></mujoco>"


class ObjectCatalog:
    """Per-object arrays (n objects × ``MAX_PARTS`` parts) read from one compiled model."""

    def __init__(self, objects: Sequence[ObjectSpec]) -> None:
        if not objects:
            raise ConfigError("object catalogue needs at least one object")
        self.objects = tuple(objects)
        n = len(objects)
        m = mujoco.MjModel.from_xml_string(_catalog_xml(objects))
        self.n_parts = np.array([len(o.parts) for o in objects], dtype=np.intp)
        self.geom_type = np.zeros((n, MAX_PARTS), dtype=np.int32)
        self.geom_size = np.zeros((n, MAX_PARTS, 3))
        self.geom_pos = np.zeros((n, MAX_PARTS, 3))
        self.geom_quat = np.tile([1.0, 0.0, 0.0, 0.0], (n, MAX_PARTS, 1))
        self.geom_rbound = np.zeros((n, MAX_PARTS))
        self.geom_aabb = np.zeros((n, MAX_PARTS, 6))
        for i in range(n):
            body = m.body(f"o{i}").id
            first = int(m.body_geomadr[body])
            k = int(m.body_geomnum[body])
            sl = slice(first, first + k)
            self.geom_type[i, :k] = m.geom_type[sl]
            self.geom_size[i, :k] = m.geom_size[sl]
            self.geom_pos[i, :k] = m.geom_pos[sl]
            self.geom_quat[i, :k] = m.geom_quat[sl]
            self.geom_rbound[i, :k] = m.geom_rbound[sl]
            self.geom_aabb[i, :k] = m.geom_aabb[sl]
        ids = [m.body(f"o{i}").id for i in range(n)]
        self.mass_kg = m.body_mass[ids].copy()
        self.inertia = m.body_inertia[ids].copy()
        self.ipos_m = m.body_ipos[ids].copy()
        self.iquat = m.body_iquat[ids].copy()
        self.rgba = np.array([o.rgba for o in objects])
        self.half_height_m = np.array([o.half_height_m for o in objects])
        self.radius_xy_m = np.array([o.radius_xy_m for o in objects])

    def __len__(self) -> int:
        return len(self.objects)


@functools.lru_cache(maxsize=4)
def catalog(split: str = "all") -> ObjectCatalog:
    return ObjectCatalog(object_set(split))


# ---- slots: writing an object into a pre-built free body ------------------------------------------
@dataclass(frozen=True)
class Slot:
    """A free body with ``MAX_PARTS`` collision geoms (and, on robosuite, a visual twin of each)."""

    body: int
    qpos_adr: int
    dof_adr: int
    geoms: np.ndarray  # (MAX_PARTS,) geoms that collide
    visuals: np.ndarray  # (MAX_PARTS,) render-only geoms, or empty when ``geoms`` are drawn

    @classmethod
    def from_names(
        cls, model: mujoco.MjModel, body: str, geoms: Sequence[str], visuals: Sequence[str] = ()
    ) -> Slot:
        b = model.body(body).id
        jnt = int(model.body_jntadr[b])
        if jnt < 0 or model.jnt_type[jnt] != mujoco.mjtJoint.mjJNT_FREE:
            raise ConfigError(f"object slot {body!r} needs a free joint")
        if len(geoms) != MAX_PARTS or len(visuals) not in (0, MAX_PARTS):
            raise ConfigError(f"object slot {body!r} needs {MAX_PARTS} geoms")
        return cls(
            body=b,
            qpos_adr=int(model.jnt_qposadr[jnt]),
            dof_adr=int(model.jnt_dofadr[jnt]),
            geoms=np.array([model.geom(g).id for g in geoms], dtype=np.intp),
            visuals=np.array([model.geom(g).id for g in visuals], dtype=np.intp),
        )


def prepare_model(model: mujoco.MjModel) -> None:
    """Slots change geometry at run time: the compile-time mid-phase trees would go stale."""
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_MIDPHASE)


def _write_geoms(
    model: mujoco.MjModel,
    geoms: np.ndarray,
    cat: ObjectCatalog,
    i: int,
    scale: float,
) -> None:
    k = int(cat.n_parts[i])
    used, unused = geoms[:k], geoms[k:]
    model.geom_type[used] = cat.geom_type[i, :k]
    model.geom_size[used] = cat.geom_size[i, :k] * scale
    model.geom_pos[used] = cat.geom_pos[i, :k] * scale
    model.geom_quat[used] = cat.geom_quat[i, :k]
    # The broad phase reads rbound and aabb: they must follow the size or contacts are missed.
    model.geom_rbound[used] = cat.geom_rbound[i, :k] * scale
    model.geom_aabb[used] = cat.geom_aabb[i, :k] * scale
    if len(unused):
        _hide(model, unused)


def _hide(model: mujoco.MjModel, geoms: np.ndarray) -> None:
    model.geom_type[geoms] = GEOM_TYPES["sphere"]
    model.geom_size[geoms] = (0.001, 0.0, 0.0)
    model.geom_pos[geoms] = 0.0
    model.geom_rbound[geoms] = 0.001
    model.geom_aabb[geoms] = (0.0, 0.0, 0.0, 0.001, 0.001, 0.001)
    model.geom_contype[geoms] = 0
    model.geom_conaffinity[geoms] = 0
    model.geom_rgba[geoms, 3] = 0.0


def write_object(
    model: mujoco.MjModel,
    slot: Slot,
    cat: ObjectCatalog,
    index: int,
    size_scale: float = 1.0,
    mass_scale: float = 1.0,
    friction: float | None = None,
    rgba: np.ndarray | None = None,
) -> None:
    """Turn ``slot`` into object ``index`` of ``cat``, scaled as the shared object DR layer does:
    size × s, mass × m, inertia × m·s² (a uniformly scaled solid of fixed mass scale).

    Call ``mujoco.mj_setConst`` after the last write of a reset: the solver's per-body weights
    depend on the masses.
    """
    k = int(cat.n_parts[index])
    g = slot.geoms
    _write_geoms(model, g, cat, index, size_scale)
    model.geom_contype[g[:k]] = 1
    model.geom_conaffinity[g[:k]] = 1
    if friction is not None:
        model.geom_friction[g[:k], 0] = friction
    colour = cat.rgba[index] if rgba is None else rgba
    if len(slot.visuals):
        v = slot.visuals
        _write_geoms(model, v, cat, index, size_scale)
        model.geom_contype[v] = 0
        model.geom_conaffinity[v] = 0
        model.geom_rgba[v[:k]] = colour
        model.geom_rgba[g, 3] = 0.0  # collision geoms are hidden by group on robosuite anyway
    else:
        model.geom_rgba[g[:k]] = colour
    b = slot.body
    model.body_mass[b] = cat.mass_kg[index] * mass_scale
    model.body_inertia[b] = cat.inertia[index] * mass_scale * size_scale * size_scale
    model.body_ipos[b] = cat.ipos_m[index] * size_scale
    model.body_iquat[b] = cat.iquat[index]


def park(model: mujoco.MjModel, data: mujoco.MjData, slot: Slot, xy_m: Sequence[float]) -> None:
    """An unused slot: a small sphere resting on the floor at ``xy_m`` (out of every view)."""
    _hide(model, slot.geoms)
    if len(slot.visuals):
        _hide(model, slot.visuals)
    g = slot.geoms[0]
    model.geom_size[g] = (PARK_RADIUS_M, 0.0, 0.0)
    model.geom_rbound[g] = PARK_RADIUS_M
    model.geom_aabb[g] = (0.0, 0.0, 0.0, PARK_RADIUS_M, PARK_RADIUS_M, PARK_RADIUS_M)
    model.geom_contype[g] = 1
    model.geom_conaffinity[g] = 1
    b = slot.body
    model.body_mass[b] = PARK_MASS_KG
    model.body_inertia[b] = 0.4 * PARK_MASS_KG * PARK_RADIUS_M**2
    model.body_ipos[b] = 0.0
    model.body_iquat[b] = (1.0, 0.0, 0.0, 0.0)
    place(data, slot, (xy_m[0], xy_m[1], PARK_RADIUS_M), 0.0)


def place(data: mujoco.MjData, slot: Slot, pos_m: Sequence[float], yaw_rad: float) -> None:
    """Set the slot's free joint: position and a rotation about the vertical, at rest."""
    a = slot.qpos_adr
    data.qpos[a : a + 3] = pos_m
    data.qpos[a + 3 : a + 7] = (math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2))
    data.qvel[slot.dof_adr : slot.dof_adr + 6] = 0.0


def sample_layout(
    rng: np.random.Generator,
    radii_m: np.ndarray,
    half_area_m: float,
    gap_m: float = 0.005,
    batch: int = 32,
    batches: int = 8,
) -> tuple[np.ndarray, bool]:
    """(k, 2) xy centres in ``[-half_area_m, half_area_m]²`` whose bounding circles do not
    overlap; ``False`` when some object had to be placed overlapping (the caller stacks it).
    Candidates are drawn ``batch`` at a time and tested at once (rejection sampling)."""
    centres = np.zeros((len(radii_m), 2))
    clear = True
    for j, r in enumerate(radii_m):
        for _ in range(batches):
            cand = rng.uniform(-half_area_m, half_area_m, (batch, 2))
            if j == 0:
                centres[j] = cand[0]
                break
            dist = np.sqrt(((cand[:, None, :] - centres[None, :j, :]) ** 2).sum(axis=2))
            ok = np.flatnonzero(np.all(dist >= radii_m[:j] + r + gap_m, axis=1))
            if len(ok):
                centres[j] = cand[ok[0]]
                break
        else:
            clear = False
            centres[j] = cand[0]
    return centres, clear


__all__ = [
    "FAMILIES",
    "MAX_PARTS",
    "OBJECT_SET_SEED",
    "OBJECT_SET_SIZE",
    "SPLITS",
    "ObjectCatalog",
    "ObjectSpec",
    "Part",
    "Slot",
    "catalog",
    "generate_object_set",
    "object_set",
    "park",
    "place",
    "prepare_model",
    "sample_layout",
    "write_object",
]
