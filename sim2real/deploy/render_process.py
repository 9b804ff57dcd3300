"""Virtual cameras as a free-running device: the mock world's two cameras render in their own
process, as USB cameras capture outside the host's control loop.

The mock arm's physics (in its own process, ``mock_arm``) publishes the scene state (``qpos``,
mocap poses, the time) into shared memory through a ``SceneStatePublisher``;
the render process snapshots it at the camera rate, renders both cameras and publishes the pair
with the snapshot's time as its capture time. The control loop reads the newest pair without
waiting. Rendering on CPU (llvmpipe) costs tens of milliseconds a pair; in its own process, at a
lower priority (``nice``), it cannot hold the host's GIL or its core when the loop wakes up.

Both shared blocks use a sequence lock (odd while written) so a reader never takes half a write.
The child exits when told to, and by itself when its parent dies. The frame block can be opened
by name in a third process (``SharedFrames``): the perception process reads the pairs there.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from multiprocessing import shared_memory
from typing import TYPE_CHECKING, Any

import numpy as np

from hardware.errors import HardwareError
from sim2real.deploy.child import child_env
from sim2real.deploy.frames import FramePair

if TYPE_CHECKING:
    from sim2real.twin_mjcf import TwinScene

# frame header (float64): per slot [lock, capture_s, seq]; then [newest slot, pairs published]
_SLOT_FIELDS = 3
_NEWEST, _PUBLISHED = 6, 7
_HEADER = 8
# state header (float64): [lock, t_s, command]; command 1: stop, 2: frozen (a dead camera)
_STATE_HEADER = 3
_STOP, _FROZEN = 1.0, 2.0


@dataclass(frozen=True)
class RenderConfig:
    twin: TwinScene  # the scene, markers included (textures are installed in the child)
    cameras: tuple[str, str] = ("cam_left", "cam_right")
    width_px: int = 640
    height_px: int = 480
    fps: float = 30.0
    nice: int = 10
    timeout_s: float = 1.0


def attach_block(name: str) -> shared_memory.SharedMemory:
    """Another process's shared block, which this process must not unlink when it exits (the
    creator owns it; Python's resource tracker would otherwise remove it under its owner)."""
    from multiprocessing import resource_tracker

    shm = shared_memory.SharedMemory(name=name)
    resource_tracker.unregister(shm._name, "shared_memory")  # type: ignore[attr-defined]
    return shm


def _write_state(
    st: np.ndarray,
    nq: int,
    nmocap: int,
    t_s: float,
    qpos: np.ndarray,
    mocap_pos: np.ndarray,
    mocap_quat: np.ndarray,
) -> None:
    """One scene state under the block's sequence lock (a few hundred bytes)."""
    st[0] += 1
    st[1] = t_s
    o = _STATE_HEADER
    st[o : o + nq] = qpos
    st[o + nq : o + nq + 3 * nmocap] = np.ravel(mocap_pos)
    st[o + nq + 3 * nmocap :] = np.ravel(mocap_quat)
    st[0] += 1


class SceneStatePublisher:
    """The writer's side of the state block, in the process that runs the physics (the mock
    arm's); the block belongs to the ``RenderedStereoCameras`` that created it."""

    def __init__(self, name: str, nq: int, nmocap: int) -> None:
        self._nq, self._nmocap = nq, nmocap
        self._shm: shared_memory.SharedMemory | None = attach_block(name)
        self._state: np.ndarray = np.ndarray(
            (_STATE_HEADER + nq + 7 * nmocap,), np.float64, self._shm.buf
        )

    def publish(
        self, t_s: float, qpos: np.ndarray, mocap_pos: np.ndarray, mocap_quat: np.ndarray
    ) -> None:
        if self._shm is not None:
            _write_state(self._state, self._nq, self._nmocap, t_s, qpos, mocap_pos, mocap_quat)

    def close(self) -> None:
        if self._shm is not None:
            del self._state
            self._shm.close()
            self._shm = None


class _Shared:
    """The two shared blocks, as numpy views."""

    def __init__(
        self,
        state_shm: shared_memory.SharedMemory,
        frames_shm: shared_memory.SharedMemory,
        n_state: int,
        h: int,
        w: int,
    ) -> None:
        self.state_shm, self.frames_shm = state_shm, frames_shm
        self.state: np.ndarray = np.ndarray((_STATE_HEADER + n_state,), np.float64, state_shm.buf)
        self.header: np.ndarray = np.ndarray((_HEADER,), np.float64, frames_shm.buf)
        self.images: np.ndarray = np.ndarray(
            (2, 2, h, w, 3), np.uint8, frames_shm.buf, offset=8 * _HEADER
        )

    @classmethod
    def attach(cls, names: tuple[str, str], n_state: int, h: int, w: int) -> _Shared:
        """The child's view of the parent's blocks."""
        blocks = [attach_block(n) for n in names]
        return cls(blocks[0], blocks[1], n_state, h, w)

    def release(self) -> None:
        # numpy views must go before the buffers close
        del self.state, self.header, self.images
        self.state_shm.close()
        self.frames_shm.close()


def _render_main(cfg: RenderConfig, names: tuple[str, str], sizes: tuple[int, int, int]) -> None:
    """The child: render the published state at ``cfg.fps`` until stopped or orphaned."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops us
    parent = os.getppid()
    with contextlib.suppress(OSError):
        os.nice(cfg.nice)
    import mujoco

    from sim2real.deploy.marker_textures import install_marker_textures
    from sim2real.rendering import FastRenderer

    nq, nmocap, n_state = sizes
    model = cfg.twin.model()
    install_marker_textures(model)
    data = mujoco.MjData(model)
    shared = _Shared.attach(names, n_state, cfg.height_px, cfg.width_px)
    renderer = FastRenderer(model, cfg.width_px, cfg.height_px)
    period = 1.0 / cfg.fps
    next_t = time.monotonic()
    try:
        while shared.state[2] != _STOP and os.getppid() == parent:
            snap = _read_locked(shared.state, _STATE_HEADER)
            if snap is not None and snap[1] >= 0.0 and snap[2] != _FROZEN:
                t_s = float(snap[1])
                body = snap[_STATE_HEADER:]
                data.qpos[:] = body[:nq]
                data.mocap_pos[:] = body[nq : nq + 3 * nmocap].reshape(nmocap, 3)
                data.mocap_quat[:] = body[nq + 3 * nmocap :].reshape(nmocap, 4)
                mujoco.mj_kinematics(model, data)
                mujoco.mj_comPos(model, data)
                mujoco.mj_camlight(model, data)
                left = renderer.render(data, cfg.cameras[0])[:, :, ::-1]
                right = renderer.render(data, cfg.cameras[1])[:, :, ::-1]
                _publish(shared, left, right, t_s)
            next_t += period
            sleep = next_t - time.monotonic()
            if sleep > 0:
                time.sleep(sleep)
            else:
                next_t = time.monotonic()  # a slow render drops frames, as a busy camera does
    finally:
        renderer.close()
        shared.release()


def _frame_views(buf: Any, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """(header, images) views of a frame block's buffer."""
    header: np.ndarray = np.ndarray((_HEADER,), np.float64, buf)
    images: np.ndarray = np.ndarray((2, 2, h, w, 3), np.uint8, buf, offset=8 * _HEADER)
    return header, images


def _frame_block_size(h: int, w: int) -> int:
    return 8 * _HEADER + 2 * 2 * h * w * 3


def _newest_capture_s(header: np.ndarray) -> float | None:
    """The newest pair's capture time from the header alone (no image copied), or None."""
    if header[_PUBLISHED] == 0:
        return None
    return float(header[int(header[_NEWEST]) * _SLOT_FIELDS + 1])


def _latest_pair(
    header: np.ndarray, images: np.ndarray, last: FramePair | None
) -> FramePair | None:
    """The newest whole pair (``last`` again when it is still the newest, or while the writer
    holds every slot)."""
    if header[_PUBLISHED] == 0:
        return None
    for _ in range(20):
        slot = int(header[_NEWEST])
        base = slot * _SLOT_FIELDS
        s1 = header[base]
        seq = int(header[base + 2])
        if last is not None and seq == last.seq:
            return last
        if s1 % 2 == 1:
            continue
        left = images[slot, 0].copy()
        right = images[slot, 1].copy()
        capture = float(header[base + 1])
        if header[base] == s1:
            return FramePair(left, right, capture, seq)
    return last


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
        self._owner = name is None
        if name is None:
            self._shm = shared_memory.SharedMemory(
                create=True, size=_frame_block_size(height_px, width_px)
            )
        else:
            self._shm = attach_block(name)
        self.header, self.images = _frame_views(self._shm.buf, height_px, width_px)
        if self._owner:
            self.header[:] = 0.0
        self._last: FramePair | None = None
        self._closed = False

    @property
    def name(self) -> str:
        return str(self._shm.name)

    def share(self) -> SharedFrames:
        return SharedFrames(self.name, self._h, self._w, self.timeout_s)

    def start(self) -> None:
        """The writer runs elsewhere."""

    def publish(self, left_bgr: np.ndarray, right_bgr: np.ndarray, capture_s: float) -> None:
        _publish_views(self.header, self.images, left_bgr, right_bgr, capture_s)

    def latest(self) -> FramePair | None:
        self._last = _latest_pair(self.header, self.images, self._last)
        return self._last

    def newest_capture_s(self) -> float | None:
        return _newest_capture_s(self.header)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        del self.header, self.images  # numpy views must go before the buffer closes
        self._shm.close()
        if self._owner:
            with contextlib.suppress(FileNotFoundError):
                self._shm.unlink()


def _read_locked(block: np.ndarray, _n_header: int) -> np.ndarray | None:
    """A consistent copy of a seqlock-guarded block, or None if it stays busy."""
    for _ in range(100):
        s1 = block[0]
        if s1 % 2 == 1:
            continue
        copy = block.copy()
        if block[0] == s1:
            return copy
    return None


def _publish(shared: _Shared, left: np.ndarray, right: np.ndarray, capture_s: float) -> None:
    _publish_views(shared.header, shared.images, left, right, capture_s)


def _publish_views(
    h: np.ndarray, images: np.ndarray, left: np.ndarray, right: np.ndarray, capture_s: float
) -> None:
    slot = 1 - int(h[_NEWEST]) if h[_PUBLISHED] > 0 else 0
    base = slot * _SLOT_FIELDS
    h[base] += 1  # odd: writing
    images[slot, 0] = left
    images[slot, 1] = right
    h[base + 1] = capture_s
    h[base + 2] = h[_PUBLISHED] + 1
    h[base] += 1  # even: done
    h[_NEWEST] = slot
    h[_PUBLISHED] += 1


class RenderedStereoCameras:
    """The host side: publish scene states, read the newest rendered pair (a ``FrameSource``)."""

    def __init__(self, cfg: RenderConfig, nq: int, nmocap: int) -> None:
        self.cfg = cfg
        self.timeout_s = cfg.timeout_s
        self._nq, self._nmocap = nq, nmocap
        self._n_state = nq + 7 * nmocap
        h, w = cfg.height_px, cfg.width_px
        self._state_shm = shared_memory.SharedMemory(
            create=True, size=8 * (_STATE_HEADER + self._n_state)
        )
        self._frames_shm = shared_memory.SharedMemory(create=True, size=_frame_block_size(h, w))
        self._shared = _Shared(self._state_shm, self._frames_shm, self._n_state, h, w)
        self._shared.state[:] = 0.0
        self._shared.state[1] = -1.0  # no state yet
        self._shared.header[:] = 0.0
        self._proc: Any = None
        self._last: FramePair | None = None
        self.pairs_read = 0

    def start(self) -> None:
        """Start the render process: ``python -m sim2real.deploy.render_process`` (not
        multiprocessing: a spawned child would re-import the user's ``__main__`` script)."""
        names = (self._state_shm.name, self._frames_shm.name)
        job = (self.cfg, names, (self._nq, self._nmocap, self._n_state))
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "sim2real.deploy.render_process"],
            stdin=subprocess.PIPE,
            stdout=subprocess.DEVNULL,  # nothing of the child's may land in a --json stdout
            close_fds=True,
            env=child_env(),  # single-threaded BLAS: no worker thread to wait on
        )
        assert self._proc.stdin is not None
        self._proc.stdin.write(pickle.dumps(job))
        self._proc.stdin.close()

    def publish(
        self, t_s: float, qpos: np.ndarray, mocap_pos: np.ndarray, mocap_quat: np.ndarray
    ) -> None:
        """A scene state from this process (the mock arm's physics uses a
        ``SceneStatePublisher`` on ``state_block`` from its own)."""
        if self._state_shm is None:
            return  # closed
        _write_state(self._shared.state, self._nq, self._nmocap, t_s, qpos, mocap_pos, mocap_quat)

    @property
    def state_block(self) -> str:
        """The state block's name, for a ``SceneStatePublisher`` in another process."""
        return str(self._state_shm.name)

    def _check_alive(self) -> None:
        if self._proc is not None and self._proc.poll() is not None:
            raise HardwareError(f"the virtual camera process died (exit {self._proc.returncode})")

    def latest(self) -> FramePair | None:
        self._check_alive()
        pair = _latest_pair(self._shared.header, self._shared.images, self._last)
        if pair is not None and pair is not self._last:
            self.pairs_read += 1
        self._last = pair
        return pair

    def newest_capture_s(self) -> float | None:
        """The newest pair's capture time without copying its images (the control loop's
        freshness check, while perception reads the pairs in its own process)."""
        self._check_alive()
        return _newest_capture_s(self._shared.header)

    def share(self) -> SharedFrames:
        """The frame block, for a reader in another process (perception)."""
        return SharedFrames(
            str(self._frames_shm.name), self.cfg.height_px, self.cfg.width_px, self.timeout_s
        )

    def freeze(self) -> None:
        """Fault injection: the cameras stop delivering (the process lives on, as a hung USB
        camera does); the loop's freshness check must notice."""
        self._shared.state[2] = _FROZEN

    @property
    def pairs_published(self) -> int:
        return int(self._shared.header[_PUBLISHED])

    def close(self) -> None:
        if self._proc is not None:
            self._shared.state[2] = _STOP
            try:
                self._proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait(timeout=2.0)
            self._proc = None
        if self._state_shm is not None:
            self._shared.release()
            for shm in (self._state_shm, self._frames_shm):
                with contextlib.suppress(FileNotFoundError):
                    shm.unlink()
            self._state_shm = None  # type: ignore[assignment]


def main() -> None:
    """The render process's entry point: the job arrives pickled on stdin."""
    cfg, names, sizes = pickle.load(sys.stdin.buffer)
    _render_main(cfg, names, sizes)


if __name__ == "__main__":
    main()
