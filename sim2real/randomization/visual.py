"""Visual DR: lights, colours, camera pose and field of view (pixel policies, virtual cameras)."""

from __future__ import annotations

from collections.abc import Mapping

import mujoco
import numpy as np

from sim2real.randomization.base import ModelIds, ModelSnapshot, Params
from sim2real.randomization.config import Range


def _unit_dirs(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.standard_normal((n, 3))
    # np.linalg.norm(v, axis=1, keepdims=True)'s arithmetic, without its overhead (every reset)
    return v / np.sqrt(np.add.reduce(v * v, axis=1, keepdims=True))


def sample(rng: np.random.Generator, ranges: Mapping[str, Range], ids: ModelIds) -> Params:
    n_l, n_g, n_c = len(ids.lights), len(ids.colour_geoms), len(ids.cameras)
    light_jitter = ranges["light_pos_jitter_m"].sample(rng, n_l)
    cam_jitter = ranges["camera_pos_jitter_m"].sample(rng, n_c)
    rgba_mag = ranges["rgba_jitter"].sample(rng, n_g)
    return {
        "light_diffuse_scale": ranges["light_diffuse_scale"].sample(rng, n_l),
        "light_pos_offset_m": _unit_dirs(rng, n_l) * np.reshape(light_jitter, (-1, 1)),
        "rgba_offset": rng.uniform(-1.0, 1.0, (n_g, 3)) * np.reshape(rgba_mag, (-1, 1)),
        "camera_pos_offset_m": _unit_dirs(rng, n_c) * np.reshape(cam_jitter, (-1, 1)),
        "camera_fovy_offset_deg": ranges["camera_fovy_jitter_deg"].sample(rng, n_c),
    }


def apply(model: mujoco.MjModel, nominal: ModelSnapshot, ids: ModelIds, params: Params) -> None:
    lights, geoms, cams = ids.lights, ids.colour_geoms, ids.cameras
    scale = np.reshape(params["light_diffuse_scale"], (-1, 1))
    # np.minimum(np.maximum(...)) is np.clip's arithmetic at a third of its cost on small arrays
    diffuse = nominal["light_diffuse"][lights] * scale
    model.light_diffuse[lights] = np.minimum(np.maximum(diffuse, 0.0), 1.0)
    model.light_pos[lights] = nominal["light_pos"][lights] + params["light_pos_offset_m"]
    rgba = nominal["geom_rgba"][geoms].copy()
    rgba[:, :3] = np.minimum(np.maximum(rgba[:, :3] + params["rgba_offset"], 0.0), 1.0)
    model.geom_rgba[geoms] = rgba
    model.cam_pos[cams] = nominal["cam_pos"][cams] + params["camera_pos_offset_m"]
    model.cam_fovy[cams] = nominal["cam_fovy"][cams] + params["camera_fovy_offset_deg"]
