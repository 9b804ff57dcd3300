"""Sampling points the arm can actually reach (FK of joint samples, not a guessed box)."""

from __future__ import annotations

import numpy as np

from hardware.spec import ArmSpec

MIN_HEIGHT_M = 0.03  # keep targets above the table with finger clearance
MIN_RADIUS_M = 0.08  # keep clear of the base and turret
LIMIT_MARGIN_RAD = 0.1  # targets need some joint travel left for the last correction


def sample_reachable(
    spec: ArmSpec, rng: np.random.Generator, min_height_m: float = MIN_HEIGHT_M
) -> np.ndarray:
    """A tool position (3,) from uniform joint angles inside the limits (with margin)."""
    lo = spec.lower_rad + LIMIT_MARGIN_RAD
    hi = spec.upper_rad - LIMIT_MARGIN_RAD
    for _ in range(1000):
        p = spec.forward_kinematics(rng.uniform(lo, hi))
        if p[2] >= min_height_m and np.hypot(p[0], p[1]) >= MIN_RADIUS_M:
            return p
    raise RuntimeError(f"spec {spec.name!r}: no reachable point above {min_height_m} m found")
