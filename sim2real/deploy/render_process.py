"""Virtual cameras as a free-running device: the mock world's two cameras render in their own
process, as USB cameras capture outside the host's control loop.

The mock arm's physics (in its own process, ``mock_arm``) publishes the scene state (``qpos``,
mocap poses, the time) into shared memory, a ``SceneStateBlock`` it attaches by name;
the render process snapshots it at the camera rate, renders both cameras and publishes the pair
with the snapshot's time as its capture time. The control loop reads the newest pair without
waiting. Rendering on CPU (llvmpipe) costs tens of milliseconds a pair; in its own process, at a
lower priority (``nice``), it cannot hold the host's GIL or its core when the loop wakes up.

Both shared blocks use the sequence lock of ``child`` (odd while written) so a reader never
takes half a write. The child is a ``child.ChildProcess``: it starts with a ready handshake,
stops when told to and dies with its parent. The frame block can be opened by name in a third
process (``SharedFrames``): the perception process reads the pairs there.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sim2real.deploy import child
from sim2real.deploy.frames import FramePair

if TYPE_CHECKING:
    from sim2real.twin_mjcf import TwinScene

# frame header (float64): per slot [lock, capture_s, seq]; then [newest slot, pairs published]
_SLOT_FIELDS = 3
_NEWEST, _PUBLISHED = 6, 7
_HEADER = 8
# state header (float64): [lock, t_s, command, ghost yaw]; the command is a fault injected by
# the host: 2 frozen (no new frames: a dead camera), 3 stuck (the last image again with fresh
# capture times: a driver that repeats its buffer), 4 ghost (the arm drawn turned by the ghost
# yaw about the base: the cameras see the wrist plate where the arm is not, a false detection)
_STATE_HEADER = 4
_FROZEN, _STUCK, _GHOST = 2.0, 3.0, 4.0


@dataclass(frozen=True)
class RenderConfig:
    twin: TwinScene  # the scene, markers included (textures are installed in the child)
    cameras: tuple[str, str] = ("cam_left", "cam_right")
    width_px: int = 640
    height_px: int = 480
    fps: float = 30.0
    nice: int = 10
    timeout_s: float = 1.0


class SceneStateBlock:
    """The scene state (time, ``qpos``, mocap poses) under a sequence lock: created by the
    cameras' host (``RenderedStereoCameras``), written by the physics (the mock arm's process
    attaches it by name), read by the render process."""

    def __init__(self, nq: int, nmocap: int, name: str | None = None) -> None:
        self.nq, self.nmocap = nq, nmocap
        size = _STATE_HEADER + nq + 7 * nmocap
        self._block = child.SharedBlock(8 * size, name)
        self.values: np.ndarray = self._block.array(size)
        if name is None:
            self.values[:] = 0.0
            self.values[1] = -1.0  # no state yet

    @property
    def name(self) -> str:
        return self._block.name

    def publish(
        self, t_s: float, qpos: np.ndarray, mocap_pos: np.ndarray, mocap_quat: np.ndarray
    ) -> None:
        """One scene state (a few hundred bytes)."""
        if self._block.closed:
            return
        st, o, nq, nm = self.values, _STATE_HEADER, self.nq, self.nmocap
        with child.seqlock(st):
            st[1] = t_s
            st[o : o + nq] = qpos
            st[o + nq : o + nq + 3 * nm] = np.ravel(mocap_pos)
            st[o + nq + 3 * nm :] = np.ravel(mocap_quat)

    def snapshot(self) -> np.ndarray | None:
        return child.read_consistent(self.values, self.values.copy)

    def close(self) -> None:
        if not self._block.closed:
            del self.values  # the view goes before the buffer closes
            self._block.close()


def _render_main(channel: child.ChildChannel) -> None:
    """The child: render the published state at ``cfg.fps`` until stopped or orphaned."""
    import mujoco

    from sim2real.deploy.marker_textures import install_marker_textures
    from sim2real.rendering import FastRenderer

    cfg, state_name, frames_name, (nq, nmocap) = channel.job
    model = cfg.twin.model()
    install_marker_textures(model)
    data = mujoco.MjData(model)
    state = SceneStateBlock(nq, nmocap, state_name)
    frames = FrameBlock(cfg.height_px, cfg.width_px, name=frames_name)
    renderer = FastRenderer(model, cfg.width_px, cfg.height_px)
    period = 1.0 / cfg.fps
    yaw_adr = int(model.jnt_qposadr[model.body_jntadr[model.body("turret").id]])
    last: tuple[np.ndarray, np.ndarray] | None = None
    next_t = time.monotonic()
    channel.ready()
    try:
        while not channel.stop_requested():
            snap = state.snapshot()
            if snap is not None and snap[1] >= 0.0 and snap[2] == _STUCK and last is not None:
                frames.publish(*last, float(snap[1]))
            elif snap is not None and snap[1] >= 0.0 and snap[2] != _FROZEN:
                body = snap[_STATE_HEADER:]
                data.qpos[:] = body[:nq]
                if snap[2] == _GHOST:
                    data.qpos[yaw_adr] += snap[3]
                data.mocap_pos[:] = body[nq : nq + 3 * nmocap].reshape(nmocap, 3)
                data.mocap_quat[:] = body[nq + 3 * nmocap :].reshape(nmocap, 4)
                mujoco.mj_kinematics(model, data)
                mujoco.mj_comPos(model, data)
                mujoco.mj_camlight(model, data)
                left = renderer.render(data, cfg.cameras[0])[:, :, ::-1]
                right = renderer.render(data, cfg.cameras[1])[:, :, ::-1]
                frames.publish(left, right, float(snap[1]))
                last = (left, right)
            next_t += period
            sleep = next_t - time.monotonic()
            if sleep > 0:
                time.sleep(sleep)
            else:
                next_t = time.monotonic()  # a slow render drops frames, as a busy camera does
    finally:
        renderer.close()
        state.close()
        frames.close()


def _frame_block_size(h: int, w: int) -> int:
    return 8 * _HEADER + 2 * 2 * h * w * 3


@dataclass(frozen=True)
class SharedFrames:
    """How another process opens a frame block (picklable): its name and image size."""

    name: str
    height_px: int
    width_px: int
    timeout_s: float

    def open(self) -> FrameBlock:
        return FrameBlock(self.height_px, self.width_px, self.timeout_s, name=self.name)


class FrameBlock:
    """A stereo frame block in shared memory (two slots, each under its own sequence lock): a
    ``FrameSource`` for its readers. ``name=None`` creates it (this process owns and unlinks
    it); a name attaches to another process's block."""

    def __init__(
        self, height_px: int, width_px: int, timeout_s: float = 1.0, name: str | None = None
    ) -> None:
        self.timeout_s = timeout_s
        self._h, self._w = height_px, width_px
        self._block = child.SharedBlock(_frame_block_size(height_px, width_px), name)
        self.header: np.ndarray = self._block.array(_HEADER)
        self.images: np.ndarray = self._block.array(
            (2, 2, height_px, width_px, 3), np.uint8, offset=8 * _HEADER
        )
        if name is None:
            self.header[:] = 0.0
        self._last: FramePair | None = None

    @property
    def name(self) -> str:
        return self._block.name

    def share(self) -> SharedFrames:
        return SharedFrames(self.name, self._h, self._w, self.timeout_s)

    def start(self) -> None:
        """The writer runs elsewhere."""

    def publish(self, left_bgr: np.ndarray, right_bgr: np.ndarray, capture_s: float) -> None:
        """Into the slot not holding the newest pair, so a reader copies the newest whole."""
        h, images = self.header, self.images
        slot = 1 - int(h[_NEWEST]) if h[_PUBLISHED] > 0 else 0
        base = slot * _SLOT_FIELDS
        with child.seqlock(h, base):
            images[slot, 0] = left_bgr
            images[slot, 1] = right_bgr
            h[base + 1] = capture_s
            h[base + 2] = h[_PUBLISHED] + 1
        h[_NEWEST] = slot
        h[_PUBLISHED] += 1

    def latest(self) -> FramePair | None:
        """The newest whole pair (the previous one again when it is still the newest, or while
        the writer holds every slot)."""
        h = self.header
        if h[_PUBLISHED] == 0:
            return None
        for _ in range(20):
            slot = int(h[_NEWEST])
            base = slot * _SLOT_FIELDS
            if self._last is not None and int(h[base + 2]) == self._last.seq:
                return self._last
            pair = child.read_consistent(h, functools.partial(self._copy, slot), at=base, tries=1)
            if pair is not None:
                self._last = pair
                return pair
        return self._last

    def _copy(self, slot: int) -> FramePair:
        base = slot * _SLOT_FIELDS
        left, right = self.images[slot, 0].copy(), self.images[slot, 1].copy()
        return FramePair(left, right, float(self.header[base + 1]), int(self.header[base + 2]))

    def newest_capture_s(self) -> float | None:
        """The newest pair's capture time from the header alone (no image copied), or None."""
        if self.header[_PUBLISHED] == 0:
            return None
        return float(self.header[int(self.header[_NEWEST]) * _SLOT_FIELDS + 1])

    @property
    def pairs_published(self) -> int:
        return int(self.header[_PUBLISHED])

    def close(self) -> None:
        if not self._block.closed:
            del self.header, self.images  # numpy views must go before the buffer closes
            self._block.close()


class RenderedStereoCameras:
    """The host side: publish scene states, read the newest rendered pair (a ``FrameSource``)."""

    def __init__(self, cfg: RenderConfig, nq: int, nmocap: int) -> None:
        self.cfg = cfg
        self.timeout_s = cfg.timeout_s
        self._nq, self._nmocap = nq, nmocap
        self._state = SceneStateBlock(nq, nmocap)
        self._frames = FrameBlock(cfg.height_px, cfg.width_px, cfg.timeout_s)
        self._child: child.ChildProcess | None = None
        self._last: FramePair | None = None
        self._closed = False
        self.pairs_read = 0

    def start(self) -> None:
        """Start the render process without waiting for it: its first frames say it is ready
        (the loop waits for them), and ``latest`` reports a child that failed to start."""
        job = (self.cfg, self._state.name, self._frames.name, (self._nq, self._nmocap))
        self._child = child.ChildProcess("virtual camera process", "sim2real.deploy.render_process",
                                   job, nice=self.cfg.nice)  # fmt: skip
        self._child.launch()

    def publish(
        self, t_s: float, qpos: np.ndarray, mocap_pos: np.ndarray, mocap_quat: np.ndarray
    ) -> None:
        """A scene state from this process (the mock arm's physics attaches ``state_block``
        from its own)."""
        if not self._closed:
            self._state.publish(t_s, qpos, mocap_pos, mocap_quat)

    @property
    def state_block(self) -> str:
        """The state block's name, for a writer in another process."""
        return self._state.name

    def _check_alive(self) -> None:
        if self._child is not None:
            self._child.check_alive()

    def latest(self) -> FramePair | None:
        self._check_alive()
        pair = self._frames.latest()
        if pair is not None and pair is not self._last:
            self.pairs_read += 1
        self._last = pair
        return pair

    def newest_capture_s(self) -> float | None:
        """The newest pair's capture time without copying its images (the control loop's
        freshness check, while perception reads the pairs in its own process)."""
        self._check_alive()
        return self._frames.newest_capture_s()

    def share(self) -> SharedFrames:
        """The frame block, for a reader in another process (perception)."""
        return self._frames.share()

    def freeze(self) -> None:
        """Fault injection: the cameras stop delivering (the process lives on, as a hung USB
        camera does); the loop's freshness check must notice."""
        self._state.values[2] = _FROZEN

    def stick(self) -> None:
        """Fault injection: the cameras deliver their last image again and again with fresh
        capture times (a driver repeating its buffer); perception's frozen check must notice."""
        self._state.values[2] = _STUCK

    def ghost(self, yaw_rad: float) -> None:
        """Fault injection: the arm is drawn turned ``yaw_rad`` about the base (the wrist plate
        seen where the arm is not: a false detection) until ``heal``; the plate gate must
        reject it."""
        self._state.values[3] = float(yaw_rad)
        self._state.values[2] = _GHOST

    def heal(self) -> None:
        """The injected camera fault ends: frames as the scene is."""
        self._state.values[2] = 0.0

    @property
    def pairs_published(self) -> int:
        return self._frames.pairs_published

    def close(self) -> None:
        if self._child is not None:
            self._child.stop()
            self._child = None
        if not self._closed:
            self._closed = True
            self._state.close()
            self._frames.close()


def main() -> None:
    """The render process's entry point (``child.run_child``)."""
    child.run_child(_render_main)


if __name__ == "__main__":
    main()
