"""Camera-to-arm registration: ``base_T_cam`` from point correspondences (Kabsch / Umeyama).

The arm carries a marker to known positions in its base frame; the stereo rig measures the same
positions in the left camera frame. The rigid transform that best maps one set onto the other in
the least-squares sense is the registration, and the per-point residuals say how much to trust it.
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from calibration.camera import fs_dumps, fs_loads, fs_mat, read_text
from calibration.errors import CalibrationFileError, RegistrationError
from s2r_common.atomic import atomic_write_text

MIN_CORRESPONDENCES = 4


def umeyama(
    src: np.ndarray, dst: np.ndarray, with_scale: bool = False
) -> tuple[np.ndarray, np.ndarray, float]:
    """R (3,3), t (3,), s minimising Σ‖dst − (s·R·src + t)‖² (Umeyama 1991; s = 1 is Kabsch).

    ``src`` and ``dst`` are (N,3). The SVD sign correction guarantees a rotation, never a
    reflection, even for noisy or nearly planar points.
    """
    src = np.asarray(src, np.float64).reshape(-1, 3)
    dst = np.asarray(dst, np.float64).reshape(-1, 3)
    if len(src) != len(dst) or len(src) < 3:
        raise RegistrationError(
            f"need the same number (≥ 3) of source and target points, got {len(src)} and {len(dst)}"
        )
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, S, Vt = np.linalg.svd(cov)
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    scale = 1.0
    if with_scale:
        var_s = float(np.sum(xs**2) / len(src))
        if var_s <= 0:
            raise RegistrationError("source points are all identical")
        scale = float(np.trace(np.diag(S) @ D) / var_s)
    t = mu_d - scale * R @ mu_s
    return R, t, scale


def transform_points(a_T_b: np.ndarray, b_p: np.ndarray) -> np.ndarray:
    """Points (N,3) in frame b → frame a."""
    pts = np.asarray(b_p, np.float64).reshape(-1, 3)
    return pts @ a_T_b[:3, :3].T + a_T_b[:3, 3]


@dataclass(frozen=True, eq=False)
class Registration:
    """``base_T_cam`` (4×4) and the residuals of the correspondences it was fitted to."""

    base_T_cam: np.ndarray  # noqa: N815 (frame names)
    residuals_m: np.ndarray  # (N,) distance between mapped camera points and arm points
    names: tuple[str, ...] = ()

    @property
    def rms_m(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_m**2)))

    @property
    def max_m(self) -> float:
        return float(np.max(self.residuals_m))

    def summary(self) -> dict[str, Any]:
        names = self.names or tuple(str(i) for i in range(len(self.residuals_m)))
        return {
            "base_T_cam": self.base_T_cam.tolist(),
            "points": len(self.residuals_m),
            "rms_m": self.rms_m,
            "max_m": self.max_m,
            "residuals_m": {n: float(r) for n, r in zip(names, self.residuals_m, strict=True)},
        }

    def save(self, path: str | os.PathLike[str]) -> Path:
        """FileStorage YAML with ``base_T_cam`` and the residual figures, written atomically."""
        return atomic_write_text(
            path,
            fs_dumps(
                {
                    "base_T_cam": self.base_T_cam,
                    "rms_m": self.rms_m,
                    "max_m": self.max_m,
                    "residuals_m": self.residuals_m.reshape(1, -1),
                }
            ),
        )


def load_base_T_cam(path: str | os.PathLike[str]) -> np.ndarray:
    """Read ``base_T_cam`` back from a registration file."""
    fs = fs_loads(read_text(path), str(path))
    T = fs_mat(fs, "base_T_cam", str(path))
    if T.shape != (4, 4) or not _is_rigid(T):
        raise CalibrationFileError(f"{path}: base_T_cam is not a rigid 4x4 transform")
    return T


def _is_rigid(T: np.ndarray) -> bool:
    R = T[:3, :3]
    return bool(
        np.allclose(R @ R.T, np.eye(3), atol=1e-6)
        and np.isclose(np.linalg.det(R), 1.0, atol=1e-6)
        and np.allclose(T[3], [0, 0, 0, 1])
    )


def register(cam_p: np.ndarray, base_p: np.ndarray, names: Sequence[str] = ()) -> Registration:
    """Fit ``base_T_cam`` so that ``base_p ≈ base_T_cam · cam_p``; both (N,3) in metres.

    Refuses fewer than four points and points that are (nearly) collinear, for which the rotation
    about their common line is undetermined.
    """
    cam = np.asarray(cam_p, np.float64).reshape(-1, 3)
    base = np.asarray(base_p, np.float64).reshape(-1, 3)
    if len(cam) != len(base):
        raise RegistrationError(f"{len(cam)} camera points but {len(base)} arm points")
    if len(cam) < MIN_CORRESPONDENCES:
        raise RegistrationError(
            f"registration needs at least {MIN_CORRESPONDENCES} correspondences, got {len(cam)}"
        )
    if not (np.all(np.isfinite(cam)) and np.all(np.isfinite(base))):
        raise RegistrationError("correspondences contain NaN or infinite coordinates")
    for what, pts in (("camera", cam), ("arm", base)):
        sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
        if sv[1] < 1e-3 * max(sv[0], 1e-12) or sv[0] < 1e-9:
            raise RegistrationError(
                f"the {what} points are collinear (singular values {sv.round(6).tolist()}): "
                "move the marker to positions that span a plane or a volume"
            )
    R, t, _ = umeyama(cam, base)
    base_T_cam = np.eye(4)
    base_T_cam[:3, :3], base_T_cam[:3, 3] = R, t
    residuals = np.linalg.norm(transform_points(base_T_cam, cam) - base, axis=1)
    return Registration(base_T_cam, residuals, tuple(names))


_POINT_COLUMNS = ("cam_x", "cam_y", "cam_z", "base_x", "base_y", "base_z")


def read_correspondences(path: str | os.PathLike[str]) -> tuple[list[str], np.ndarray, np.ndarray]:
    """A CSV with a header ``name,cam_x,cam_y,cam_z,base_x,base_y,base_z`` (metres).

    ``name`` is optional. Returns names, camera points (N,3) and arm points (N,3).
    """
    reader = csv.DictReader(io.StringIO(read_text(path)))
    header = [h.strip() for h in reader.fieldnames or []]
    rows = list(reader)
    missing = [c for c in _POINT_COLUMNS if c not in header]
    if missing:
        raise CalibrationFileError(
            f"{path}: missing column(s) {', '.join(missing)}; expected "
            f"name,{','.join(_POINT_COLUMNS)}"
        )
    names, cam, base = [], [], []
    for line, row in enumerate(rows, start=2):
        try:
            values = [float(row[c]) for c in _POINT_COLUMNS]
        except (TypeError, ValueError):
            raise CalibrationFileError(f"{path}:{line}: not a number in {dict(row)}") from None
        if not all(math.isfinite(v) for v in values):
            raise CalibrationFileError(f"{path}:{line}: non-finite coordinate in {dict(row)}")
        names.append(row.get("name") or str(line - 2))
        cam.append(values[:3])
        base.append(values[3:])
    return names, np.array(cam).reshape(-1, 3), np.array(base).reshape(-1, 3)


def read_targets(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """A CSV ``name,base_x,base_y,base_z``: where the arm put the marker for each image name."""
    reader = csv.DictReader(io.StringIO(read_text(path)))
    columns = ("name", "base_x", "base_y", "base_z")
    header = [h.strip() for h in reader.fieldnames or []]
    rows = list(reader)
    missing = [c for c in columns if c not in header]
    if missing:
        raise CalibrationFileError(
            f"{path}: missing column(s) {', '.join(missing)}; expected {','.join(columns)}"
        )
    targets: dict[str, np.ndarray] = {}
    for line, row in enumerate(rows, start=2):
        try:
            targets[str(row["name"])] = np.array([float(row[c]) for c in columns[1:]])
        except (TypeError, ValueError):
            raise CalibrationFileError(f"{path}:{line}: not a number in {dict(row)}") from None
    return targets
