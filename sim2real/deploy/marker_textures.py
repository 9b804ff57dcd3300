"""ArUco images for the deploy scenes' marker textures.

MJCF's built-in textures cannot draw an ArUco pattern, so ``sim2real.model`` declares flat
``aruco_<id>`` textures and this module writes the marker images into ``model.tex_data`` after
compilation (before any renderer uploads the textures).
"""

from __future__ import annotations

import cv2
import mujoco
import numpy as np

from sim2real import model as names

TEXTURE_PREFIX = "aruco_"


def marker_image(
    marker_id: int, side_px: int = names.MARKER_TEXTURE_PX, fill: float | None = None
) -> np.ndarray:
    """(side, side) uint8: the ArUco marker (black square = ``fill`` of the side, by default the
    id's fill in the scene, ``names.marker_fill``) on a white margin."""
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, names.MARKER_DICTIONARY))
    inner = round(side_px * (names.marker_fill(marker_id) if fill is None else fill))
    img = cv2.aruco.generateImageMarker(dictionary, marker_id, inner, borderBits=1)
    pad = side_px - inner
    return cv2.copyMakeBorder(
        img, pad // 2, pad - pad // 2, pad // 2, pad - pad // 2, cv2.BORDER_CONSTANT, value=(255,)
    )


def marker_texture_ids(model: mujoco.MjModel) -> list[int]:
    """The marker ids of the model's ``aruco_<id>`` textures (plates, cube faces, seam ends)."""
    ids = []
    for t in range(model.ntex):
        name = model.texture(t).name
        if name.startswith(TEXTURE_PREFIX) and name[len(TEXTURE_PREFIX) :].isdigit():
            ids.append(int(name[len(TEXTURE_PREFIX) :]))
    return ids


def install_marker_textures(model: mujoco.MjModel) -> None:
    """Write the ArUco images into every flat ``aruco_<id>`` texture (before any renderer
    exists: a renderer uploads the textures once, when it is made)."""
    for marker_id in marker_texture_ids(model):
        tex = model.texture(f"{TEXTURE_PREFIX}{marker_id}")
        h, w, c = int(tex.height[0]), int(tex.width[0]), int(tex.nchannel[0])
        img = np.repeat(marker_image(marker_id, w)[:, :, None], c, axis=2)
        adr = int(tex.adr[0])
        model.tex_data[adr : adr + h * w * c] = img.ravel()
