"""The marker cube and the seam's end markers: geometry only (numpy, no OpenCV at import).

A pick policy needs the cube's position and yaw. The cube carries one ArUco marker on each of
its five visible faces (the bottom rests on the table), so that whichever way it lies some face
faces the cameras, and the gripper hiding one or two faces still leaves others. The geometry
lives here, outside ``sim2real``, because three users share it: the MuJoCo twin (which renders
textured faces), the printable sheet (``sim2real calibrate cube-sheet``) and the tracker
(:mod:`calibration.cube_tracker`).

Each face has a frame ``cube_T_face`` whose z axis points out of the face and whose y axis is the
marker's "up". On the side faces "up" is the cube's top face, which is what folding the printed
net gives (:func:`face_net_layout`). The tracker's rigid fit over all faces relies on that
orientation; its per-face estimate (:func:`centre_and_yaw`, the fit's start and its fallback)
uses only each marker's normal and, on a horizontal face, an edge direction, so a marker glued
turned by 90° still gives the centre and yaw.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from calibration.errors import ConfigError

# Face name → (outward normal, marker "up") in the cube frame. The bottom face ("-z") carries no
# marker: it is on the table. The order is the order of ``MarkerCube.face_ids``.
FACE_AXES: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "+z": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "+x": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "-x": ((-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "+y": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "-y": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
}
FACE_NAMES: tuple[str, ...] = tuple(FACE_AXES)

# Yaw of a cube is defined modulo its 90° symmetry about the vertical; reported in [-45°, 45°).
YAW_PERIOD_RAD = math.pi / 2


def wrap_yaw(yaw_rad: float) -> float:
    """An angle about base z → the cube-equivalent angle in [-π/4, π/4)."""
    return float((yaw_rad + YAW_PERIOD_RAD / 2) % YAW_PERIOD_RAD - YAW_PERIOD_RAD / 2)


def mean_yaw(yaws_rad: np.ndarray, weights: np.ndarray | None = None) -> float:
    """Circular mean modulo 90°: angles are multiplied by 4 so that 44° and −44° average to 45°
    (one edge direction), not to 0°."""
    yaws = np.asarray(yaws_rad, np.float64)
    w = np.ones_like(yaws) if weights is None else np.asarray(weights, np.float64)
    c = float(np.sum(w * np.cos(4.0 * yaws)))
    s = float(np.sum(w * np.sin(4.0 * yaws)))
    return wrap_yaw(math.atan2(s, c) / 4.0)


def _dictionary_size(name: str) -> int | None:
    """How many ids a predefined ArUco dictionary name holds (``DICT_4X4_50`` → 50)."""
    match = re.fullmatch(r"DICT_\d+X\d+_(\d+)", name.upper())
    return int(match.group(1)) if match else None


def _check_ids(ids: tuple[int, ...], dictionary: str, what: str) -> None:
    if len(set(ids)) != len(ids):
        raise ConfigError(f"{what}: marker ids must be distinct, got {list(ids)}")
    capacity = _dictionary_size(dictionary)
    for i in ids:
        if not (isinstance(i, int | np.integer) and i >= 0 and (capacity is None or i < capacity)):
            limit = f" < {capacity}" if capacity else ""
            raise ConfigError(
                f"{what}: marker id {i!r} is not an id of {dictionary} (0 ≤ id{limit})"
            )


@dataclass(frozen=True)
class MarkerCube:
    """A cube of side ``size_m`` with a ``marker_m`` ArUco marker (black square) centred on each
    face listed in ``FACE_NAMES`` (top, +x, −x, +y, −y), ids ``face_ids`` in that order.

    The defaults are the pick scene's 25 mm cube with 20 mm markers (2.5 mm white margin on each
    face: ArUco needs a light quiet zone around the black border) and ids 2–6 of DICT_4X4_50
    (0 and 1 are the target and wrist plates).
    """

    size_m: float = 0.025
    marker_m: float = 0.02
    face_ids: tuple[int, ...] = (2, 3, 4, 5, 6)
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.size_m) and self.size_m > 0):
            raise ConfigError(f"cube size_m must be a positive number of metres, got {self.size_m}")
        if not (math.isfinite(self.marker_m) and 0 < self.marker_m < self.size_m):
            raise ConfigError(
                f"cube marker_m {self.marker_m} must be in (0, size_m = {self.size_m}): the "
                "marker needs a white margin on the face"
            )
        if len(self.face_ids) != len(FACE_NAMES):
            raise ConfigError(
                f"cube face_ids needs {len(FACE_NAMES)} ids (faces {', '.join(FACE_NAMES)}), "
                f"got {list(self.face_ids)}"
            )
        _check_ids(tuple(self.face_ids), self.dictionary, "cube")

    @property
    def half_m(self) -> float:
        return self.size_m / 2.0

    @property
    def marker_fill(self) -> float:
        """The black square's share of the face side."""
        return self.marker_m / self.size_m

    def face_name(self, marker_id: int) -> str:
        try:
            return FACE_NAMES[self.face_ids.index(marker_id)]
        except ValueError:
            raise ConfigError(
                f"marker id {marker_id} is not on the cube (face ids {list(self.face_ids)})"
            ) from None

    def cube_T_face(self, marker_id: int) -> np.ndarray:
        """Pose (4, 4) of the face's marker frame (x right, y up, z out) in the cube frame."""
        normal, up = (np.array(v) for v in FACE_AXES[self.face_name(marker_id)])
        T = np.eye(4)
        T[:3, :3] = np.stack([np.cross(up, normal), up, normal], axis=1)
        T[:3, 3] = self.half_m * normal
        return T

    def face_corners_m(self, marker_id: int) -> np.ndarray:
        """The marker's four corners (4, 3) in the cube frame, in ArUco order (TL, TR, BR, BL)."""
        h = self.marker_m / 2.0
        local = np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])
        T = self.cube_T_face(marker_id)
        return np.asarray(local @ T[:3, :3].T + T[:3, 3])


@dataclass(frozen=True)
class FaceObservation:
    """One face seen by both cameras: its fitted marker pose in the base frame."""

    marker_id: int
    base_T_marker: np.ndarray  # noqa: N815 (frame names) (4, 4), z out of the face
    fit_rms_m: float


def centre_and_yaw(cube: MarkerCube, face: FaceObservation) -> tuple[np.ndarray, float]:
    """What one face says: the cube centre (face centre minus half the side along the normal) and
    the yaw about base z (mod 90°).

    A vertical face gives yaw from its normal; a horizontal face from its marker's x edge. Both
    hold for any in-plane rotation of the glued marker and for a cube lying on any face.
    """
    R = face.base_T_marker[:3, :3]
    normal = R[:, 2]
    centre = face.base_T_marker[:3, 3] - cube.half_m * normal
    horizontal_face = abs(normal[2]) > math.cos(math.pi / 4)
    edge = R[:, 0] if horizontal_face else normal
    return centre, wrap_yaw(math.atan2(edge[1], edge[0]))


@dataclass(frozen=True)
class CubeFit:
    """The faces of one frame pair fused: centre (3,), yaw and how well the faces agree."""

    position_m: np.ndarray
    yaw_rad: float
    face_ids: tuple[int, ...]
    spread_m: float  # largest distance of a face's centre estimate from the fused centre
    fit_rms_m: float  # worst face's rigid-square fit residual
    reprojection_px: float | None = None  # RMS, when refined on the images (cube_tracker)


def fuse_faces(cube: MarkerCube, faces: list[FaceObservation]) -> CubeFit:
    """Average the faces' centre estimates and their yaws (circular, mod 90°)."""
    if not faces:
        raise ConfigError("fuse_faces needs at least one face")
    per_face = [centre_and_yaw(cube, f) for f in faces]
    centres = np.array([c for c, _ in per_face])
    centre = centres.mean(axis=0)
    spread = float(np.max(np.linalg.norm(centres - centre, axis=1)))
    yaw = mean_yaw(np.array([y for _, y in per_face]))
    return CubeFit(
        centre,
        yaw,
        tuple(f.marker_id for f in faces),
        spread,
        max(f.fit_rms_m for f in faces),
    )


def face_net_layout(cube: MarkerCube) -> dict[int, tuple[tuple[int, int], int]]:
    """The printable net: marker id → ((column, row) of its square, quarter turns CCW of the
    marker image), in a 3×3 grid (row 0 at the top) with the top face in the centre.

    A side face sits next to the edge it shares with the top; its marker is turned so that its
    "up" points at the centre square, which after folding is the cube's top (``FACE_AXES``).
    Looking down on the sheet, +x is to the right and +y is up (the top face's own frame).
    """
    cells = {"+z": (1, 1), "+x": (2, 1), "-x": (0, 1), "+y": (1, 0), "-y": (1, 2)}
    # Quarter turns CCW that bring the marker's up onto "towards the centre".
    turns = {"+z": 0, "+x": 1, "-x": 3, "+y": 2, "-y": 0}
    return {
        marker_id: (cells[name], turns[name])
        for marker_id, name in zip(cube.face_ids, FACE_NAMES, strict=True)
    }


@dataclass(frozen=True)
class SeamMarkers:
    """Two flat ArUco plates lying on the table beyond the two ends of a straight seam, on its
    line: the start plate ``end_offset_m`` before the start, the end plate as far past the end.

    From the two triangulated plate centres the seam is ``start = a + d·u`` and ``end = b − d·u``
    with ``u`` the unit vector from a to b. Ids 7 and 8 of DICT_4X4_50 by default (0–6 are the
    plates and the cube).
    """

    start_id: int = 7
    end_id: int = 8
    marker_m: float = 0.03
    end_offset_m: float = 0.027
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.marker_m) and self.marker_m > 0):
            raise ConfigError(f"seam marker_m must be positive, got {self.marker_m}")
        if not (math.isfinite(self.end_offset_m) and self.end_offset_m >= 0):
            raise ConfigError(f"seam end_offset_m must be ≥ 0, got {self.end_offset_m}")
        _check_ids((self.start_id, self.end_id), self.dictionary, "seam")

    def seam_ends(
        self, start_marker_m: np.ndarray, end_marker_m: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(start, end) of the seam (3,) from the two plate centres (3,)."""
        a, b = np.asarray(start_marker_m, np.float64), np.asarray(end_marker_m, np.float64)
        span = np.linalg.norm(b - a)
        if not span > 2 * self.end_offset_m:
            raise ConfigError(
                f"seam plates {span:.4f} m apart, but their offsets alone take "
                f"{2 * self.end_offset_m:.4f} m: wrong marker ids or end_offset_m"
            )
        u = (b - a) / span
        return a + self.end_offset_m * u, b - self.end_offset_m * u
