"""Visual DR: lights, colours, camera pose and field of view (pixel policies, virtual cameras)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from sim2real.randomization.base import (
    ModelIds,
    ModelSnapshot,
    Params,
    PlanCache,
    as_index,
    shown_rgba,
)
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


def apply_reference(
    model: mujoco.MjModel, nominal: ModelSnapshot, ids: ModelIds, params: Params
) -> None:
    lights, geoms, cams = ids.lights, ids.colour_geoms, ids.cameras
    scale = np.reshape(params["light_diffuse_scale"], (-1, 1))
    # np.minimum(np.maximum(...)) is np.clip's arithmetic at a third of its cost on small arrays
    diffuse = nominal["light_diffuse"][lights] * scale
    model.light_diffuse[lights] = np.minimum(np.maximum(diffuse, 0.0), 1.0)
    model.light_pos[lights] = nominal["light_pos"][lights] + params["light_pos_offset_m"]
    # jitter the colour each geom is drawn in (its material's, see ``shown_rgba``)
    rgba = shown_rgba(model, geoms, nominal["geom_rgba"], nominal["mat_rgba"])
    rgba[:, :3] = np.minimum(np.maximum(rgba[:, :3] + params["rgba_offset"], 0.0), 1.0)
    model.geom_rgba[geoms] = rgba
    model.cam_pos[cams] = nominal["cam_pos"][cams] + params["camera_pos_offset_m"]
    model.cam_fovy[cams] = nominal["cam_fovy"][cams] + params["camera_fovy_offset_deg"]


@dataclass(frozen=True)
class _Plan:
    """``apply_reference``'s ids, nominal rows and model arrays, resolved once per model."""

    lights: Any  # slice or index array (``as_index``)
    geoms: Any
    cams: Any
    diffuse: np.ndarray
    light_pos: np.ndarray
    rgba: np.ndarray
    cam_pos: np.ndarray
    fovy: np.ndarray
    model_diffuse: np.ndarray  # the model's own arrays (views of its buffers)
    model_light_pos: np.ndarray
    model_rgba: np.ndarray
    model_cam_pos: np.ndarray
    model_fovy: np.ndarray

    @classmethod
    def of(cls, model: mujoco.MjModel, nominal: ModelSnapshot, ids: ModelIds) -> _Plan:
        lights, geoms, cams = ids.lights, ids.colour_geoms, ids.cameras
        return cls(
            lights=as_index(lights),
            geoms=as_index(geoms),
            cams=as_index(cams),
            diffuse=nominal["light_diffuse"][lights],
            light_pos=nominal["light_pos"][lights],
            rgba=shown_rgba(model, geoms, nominal["geom_rgba"], nominal["mat_rgba"]),
            cam_pos=nominal["cam_pos"][cams],
            fovy=nominal["cam_fovy"][cams],
            model_diffuse=model.light_diffuse,
            model_light_pos=model.light_pos,
            model_rgba=model.geom_rgba,
            model_cam_pos=model.cam_pos,
            model_fovy=model.cam_fovy,
        )


_PLANS = PlanCache(_Plan.of)


def apply(model: mujoco.MjModel, nominal: ModelSnapshot, ids: ModelIds, params: Params) -> None:
    """``apply_reference``'s arithmetic on the same values (the same bits), written through a
    plan resolved once per model (``tests/sim2real/randomization/test_appliers.py``)."""
    p = _PLANS.get(model, nominal, ids)
    scale = np.reshape(params["light_diffuse_scale"], (-1, 1))
    # np.minimum(np.maximum(...)) is np.clip's arithmetic at a third of its cost on small arrays
    p.model_diffuse[p.lights] = np.minimum(np.maximum(p.diffuse * scale, 0.0), 1.0)
    p.model_light_pos[p.lights] = p.light_pos + params["light_pos_offset_m"]
    rgba = p.rgba.copy()
    rgba[:, :3] = np.minimum(np.maximum(rgba[:, :3] + params["rgba_offset"], 0.0), 1.0)
    p.model_rgba[p.geoms] = rgba
    p.model_cam_pos[p.cams] = p.cam_pos + params["camera_pos_offset_m"]
    p.model_fovy[p.cams] = p.fovy + params["camera_fovy_offset_deg"]
