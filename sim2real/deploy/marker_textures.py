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


def marker_image(marker_id: int, side_px: int = names.MARKER_TEXTURE_PX) -> np.ndarray:
    """(side, side) uint8: the ArUco marker (black square = MARKER_FILL of the side), white margin."""
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, names.MARKER_DICTIONARY))
    inner = round(side_px * names.MARKER_FILL)
    img = cv2.aruco.generateImageMarker(dictionary, marker_id, inner, borderBits=1)
    pad = side_px - inner
    return cv2.copyMakeBorder(
        img, pad // 2, pad - pad // 2, pad // 2, pad - pad // 2, cv2.BORDER_CONSTANT, value=(255,)
    )


def install_marker_textures(model: mujoco.MjModel) -> None:
    """Write the ArUco images into the flat ``aruco_<id>`` textures (before any renderer exists)."""
    for marker_id in (names.TARGET_MARKER_ID, names.EE_MARKER_ID):
        tex = model.texture(f"aruco_{marker_id}")
        h, w, c = int(tex.height[0]), int(tex.width[0]), int(tex.nchannel[0])
        img = np.repeat(marker_image(marker_id, w)[:, :, None], c, axis=2)
        adr = int(tex.adr[0])
        model.tex_data[adr : adr + h * w * c] = img.ravel()
