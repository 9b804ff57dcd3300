"""Object DR: cube size, mass, friction and initial pose (the pose jitter is used at reset)."""

from __future__ import annotations

from collections.abc import Mapping

import mujoco
import numpy as np

from sim2real.randomization.base import ModelIds, ModelSnapshot, Params
from sim2real.randomization.config import Range


def sample(rng: np.random.Generator, ranges: Mapping[str, Range], ids: ModelIds) -> Params:
    jitter = float(ranges["init_xy_jitter_m"].sample(rng))
    angle = rng.uniform(-np.pi, np.pi)
    return {
        "size_scale": float(ranges["size_scale"].sample(rng)),
        "mass_scale": float(ranges["mass_scale"].sample(rng)),
        "friction": float(ranges["friction"].sample(rng)),
        "init_xy_offset_m": np.array([np.cos(angle), np.sin(angle)]) * jitter,
    }


def apply(model: mujoco.MjModel, nominal: ModelSnapshot, ids: ModelIds, params: Params) -> None:
    g, b = ids.cube_geom, ids.cube_body
    if g < 0:
        return
    s = params["size_scale"]
    model.geom_size[g] = nominal["geom_size"][g] * s
    # The broad phase uses rbound/aabb: scale them with the size or contacts are missed.
    model.geom_rbound[g] = nominal["geom_rbound"][g] * s
    model.geom_aabb[g] = nominal["geom_aabb"][g] * s
    m = params["mass_scale"]
    model.body_mass[b] = nominal["body_mass"][b] * m
    # A solid box: inertia ∝ mass · size².
    model.body_inertia[b] = nominal["body_inertia"][b] * m * s * s
    model.geom_friction[g, 0] = params["friction"]
