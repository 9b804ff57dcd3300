"""Check an existing stereo calibration against a board of known size.

Triangulating the board corners and measuring the distance between neighbours gives the square
size the calibration believes in; its error in % is a direct test of scale (baseline) and
intrinsics. The distance of each right corner to its left match's epipolar line tests R, T and
the distortion model, independently of the board's size.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.boards import MIN_CHARUCO_CORNERS, BoardSpec
from calibration.errors import BoardNotFoundError
from calibration.stereo import StereoPair, align_pair
from calibration.triangulate import StereoRig


@dataclass(frozen=True)
class PairCheck:
    name: str
    square_size: float
    square_size_error_pct: float
    epipolar_rms_px: float


@dataclass(frozen=True)
class CheckResult:
    square_size_expected: float
    square_size: float  # mean over every neighbouring corner pair of every view
    square_size_error_pct: float  # signed: (measured − expected) / expected
    square_size_spread_pct: float  # RMS of the per-edge errors
    epipolar_rms_px: float
    epipolar_max_px: float
    pairs: tuple[PairCheck, ...]
    skipped: tuple[str, ...]

    def summary(self) -> dict[str, Any]:
        return {
            "square_size_expected": self.square_size_expected,
            "square_size": self.square_size,
            "square_size_error_pct": self.square_size_error_pct,
            "square_size_spread_pct": self.square_size_spread_pct,
            "epipolar_rms_px": self.epipolar_rms_px,
            "epipolar_max_px": self.epipolar_max_px,
            "pairs_used": len(self.pairs),
            "pairs_skipped": list(self.skipped),
            "per_pair": {
                p.name: {
                    "square_size_error_pct": p.square_size_error_pct,
                    "epipolar_rms_px": p.epipolar_rms_px,
                }
                for p in self.pairs
            },
        }


def neighbour_edges(object_points: np.ndarray, square: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j), i < j, of corners exactly one square apart on the board."""
    d = np.linalg.norm(object_points[:, None, :] - object_points[None, :, :], axis=2)
    i, j = np.nonzero(np.triu(np.abs(d - square) < 1e-3 * square, k=1))
    return i, j


def check_stereo(rig: StereoRig, pairs: Sequence[StereoPair], board: BoardSpec) -> CheckResult:
    """Measure ``board`` with ``rig`` in every pair where both cameras see it."""
    edge_lengths: list[np.ndarray] = []
    epipolar: list[np.ndarray] = []
    checks: list[PairCheck] = []
    skipped: list[str] = []
    for pair in pairs:
        if pair.left is None or pair.right is None:
            skipped.append(pair.name)
            continue
        left, right = align_pair(pair.left, pair.right, board)
        if len(left) < MIN_CHARUCO_CORNERS:
            skipped.append(pair.name)
            continue
        pts = rig.triangulate(left.image_points, right.image_points)
        i, j = neighbour_edges(left.object_points.astype(np.float64), board.square)
        if len(i) == 0:
            skipped.append(pair.name)
            continue
        lengths = np.linalg.norm(pts[i] - pts[j], axis=1)
        epi = rig.epipolar_errors_px(left.image_points, right.image_points)
        edge_lengths.append(lengths)
        epipolar.append(epi)
        mean = float(lengths.mean())
        checks.append(
            PairCheck(
                pair.name,
                mean,
                100.0 * (mean - board.square) / board.square,
                float(np.sqrt(np.mean(epi**2))),
            )
        )
    if not checks:
        raise BoardNotFoundError(
            f"no image pair shows the {board} in both cameras; nothing to check"
        )
    all_lengths = np.concatenate(edge_lengths)
    all_epi = np.concatenate(epipolar)
    rel = (all_lengths - board.square) / board.square
    mean = float(all_lengths.mean())
    return CheckResult(
        square_size_expected=board.square,
        square_size=mean,
        square_size_error_pct=100.0 * (mean - board.square) / board.square,
        square_size_spread_pct=100.0 * float(np.sqrt(np.mean(rel**2))),
        epipolar_rms_px=float(np.sqrt(np.mean(all_epi**2))),
        epipolar_max_px=float(all_epi.max()),
        pairs=tuple(checks),
        skipped=tuple(skipped),
    )
