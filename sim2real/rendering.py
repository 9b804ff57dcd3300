"""Offscreen rendering with the fast CPU settings measured in NOTES (about 20x the defaults)."""

from __future__ import annotations

import atexit
import weakref

import mujoco
import numpy as np

_OFF_FLAGS = (
    mujoco.mjtRndFlag.mjRND_SHADOW,
    mujoco.mjtRndFlag.mjRND_REFLECTION,
    mujoco.mjtRndFlag.mjRND_SKYBOX,
)


def apply_fast_settings(model: mujoco.MjModel) -> None:
    """No shadow maps, no multisampling: llvmpipe spends most of its time on those."""
    model.vis.quality.shadowsize = 0
    model.vis.quality.offsamples = 0


# Renderers still open; closed at interpreter exit before MuJoCo's EGL display is terminated.
_OPEN: weakref.WeakSet[FastRenderer] = weakref.WeakSet()
_CLOSE_AT_EXIT = False


def _close_open_renderers() -> None:
    for renderer in list(_OPEN):
        renderer.close()


class FastRenderer:
    """A ``mujoco.Renderer`` with shadows, reflections and skybox off.

    Close it explicitly where you can. One left open (a script that never calls ``env.close()``)
    is closed at interpreter exit, before MuJoCo terminates the EGL display: otherwise the
    renderer's ``__del__`` runs after it and prints an ``EGLError`` traceback.
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int) -> None:
        global _CLOSE_AT_EXIT
        apply_fast_settings(model)
        self._renderer = mujoco.Renderer(model, height=height, width=width)
        if not _CLOSE_AT_EXIT:
            # atexit runs last-in first-out, and MuJoCo registers ``eglTerminate`` when its first
            # context is made (just above at the latest), so this handler runs before it.
            atexit.register(_close_open_renderers)
            _CLOSE_AT_EXIT = True
        _OPEN.add(self)
        for flag in _OFF_FLAGS:
            self._renderer.scene.flags[flag] = 0
        self.width, self.height = width, height

    def render(self, data: mujoco.MjData, camera: str | int) -> np.ndarray:
        """(height, width, 3) uint8 RGB."""
        self._renderer.update_scene(data, camera=camera)
        for flag in _OFF_FLAGS:  # update_scene does not reset them, but be explicit per frame
            self._renderer.scene.flags[flag] = 0
        return self._renderer.render()

    def close(self) -> None:
        self._renderer.close()
        _OPEN.discard(self)

    def __enter__(self) -> FastRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
