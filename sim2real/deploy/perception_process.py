"""Perception in its own process: detection, triangulation and the Kalman filters off the
control process, fed by frames in shared memory (the mock's render process publishes them).

Why a process: as a thread of the control process, perception held the host's GIL for the Python
around each OpenCV call. At a lower priority than the real-time loop, on a loaded machine, it
was preempted while holding the GIL, and the loop, awake on time, waited for it (a priority
inversion no scheduler setting of the loop's can fix). Here it has a GIL of its own.

The child reads the newest pair from the frame block, measures it (``perception.PairTracker``,
the same code as the thread worker's) and publishes, under a sequence lock (odd while written),
each object's track and the wrist plate's measurement with the pair's capture time. The control
loop's ``perceive`` reads that block without waiting. A small control area, written by the
parent alone, carries the episode (epoch and reset time) and the stop request.

Lifecycle (``child.ChildProcess``): the child says it is ready once its tracker is built, exits
when told to, when its parent dies, and on any error, with one line on stderr that the parent
raises as ``HardwareError``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.kalman import TrackerConfig
from calibration.triangulate import StereoRig
from hardware.errors import HardwareError
from sim2real.deploy import child
from sim2real.deploy.frames import FramePair
from sim2real.deploy.perception import (
    MarkerLayout,
    PairTracker,
    PlateMeasurement,
    Snapshot,
    Track,
    TrackerOptions,
)
from sim2real.deploy.render_process import SharedFrames
from sim2real.envs.contract import ObjectEstimate

# header (float64): [lock, epoch, seq, capture_s, ee_seen, same_since_s, pairs, plates written]
_LOCK, _EPOCH, _SEQ, _CAPTURE, _EE_SEEN, _SAME_SINCE, _PAIRS, _PLATES = range(8)
_HEADER = 8
_RING = 32  # plate measurements kept for the parent (> 1 s of pairs at 30 fps)
_RING_FIELDS = 5  # epoch, capture_s, x, y, z
_OBJ_FIELDS = 9  # present, position xyz, velocity xyz, blind_s, yaw (nan: none)
# control (written by the parent only, outside the lock): [epoch, reset_s]
_CTL_EPOCH, _CTL_RESET = range(2)
_CTL = 2
POLL_S = 0.003  # the child's wait for a new pair (and its check on its parent)


def _layout(n_names: int) -> tuple[int, int, int]:
    """(ring offset, objects offset, control offset, in float64s) and the block's length."""
    ring = _HEADER
    objects = ring + _RING * _RING_FIELDS
    ctl = objects + n_names * _OBJ_FIELDS
    return ring, objects, ctl


def _block_len(n_names: int) -> int:
    return _layout(n_names)[2] + _CTL


@dataclass(frozen=True)
class PerceptionJob:
    """Everything the child needs (pickled over its channel, with the estimate block's name)."""

    frames: SharedFrames
    rig: StereoRig
    base_T_left: np.ndarray  # noqa: N815 - frame names are part of the name
    layout: MarkerLayout
    objects: tuple[str, ...]
    ee_tracker: TrackerConfig
    options: TrackerOptions = TrackerOptions()  # noqa: RUF009 - frozen, shared safely
    nice: int = 5

    def tracker(self) -> PairTracker:
        return PairTracker(
            self.rig, self.base_T_left, self.layout, self.objects, self.ee_tracker, self.options
        )


def _publish(
    block: np.ndarray, names: tuple[str, ...], epoch: int, seq: int, result: Any, pairs: int
) -> None:
    """One pair's result under the block's sequence lock."""
    ring, objects, _ = _layout(len(names))
    with child.seqlock(block, _LOCK):
        block[_EPOCH], block[_SEQ], block[_CAPTURE] = epoch, seq, result.capture_s
        block[_EE_SEEN] = float(result.plate_m is not None)
        block[_SAME_SINCE] = result.same_since_s
        block[_PAIRS] = pairs
        if result.plate_m is not None:
            n = int(block[_PLATES])
            o = ring + (n % _RING) * _RING_FIELDS
            block[o], block[o + 1] = epoch, result.capture_s
            block[o + 2 : o + 5] = result.plate_m
            block[_PLATES] = n + 1
        for i, name in enumerate(names):
            o = objects + i * _OBJ_FIELDS
            track = result.tracks.get(name)
            block[o] = 0.0 if track is None else 1.0
            if track is not None:
                est = track.estimate
                block[o + 1 : o + 4] = est.position_m
                block[o + 4 : o + 7] = track.velocity_mps
                block[o + 7] = est.blind_s
                block[o + 8] = math.nan if est.yaw_rad is None else est.yaw_rad


def _serve(channel: child.ChildChannel) -> None:
    """Measure each new pair of the frame block and publish the result, until stopped."""
    job, block_name = channel.job
    frames = job.frames.open()
    shm = child.SharedBlock(name=block_name)
    tracker = job.tracker()
    names = tracker.names
    block: np.ndarray = shm.array(_block_len(len(names)))
    ctl = _layout(len(names))[2]
    channel.ready()
    epoch, seq, pairs = -1, -1, 0
    try:
        while not channel.stop_requested():
            want = int(block[ctl + _CTL_EPOCH])
            if want != epoch:  # a new episode: fresh tracks
                epoch, tracker, seq = want, job.tracker(), -1
            pair = frames.latest()
            if pair is None or pair.seq == seq or pair.capture_s < block[ctl + _CTL_RESET]:
                time.sleep(POLL_S)  # nothing new, or a frame from before the reset
                continue
            seq = pair.seq
            result = tracker.observe(pair)
            pairs += 1
            if int(block[ctl + _CTL_EPOCH]) == epoch:  # not reset meanwhile
                _publish(block, names, epoch, seq, result, pairs)
    finally:
        del block
        frames.close()
        shm.close()


def main() -> None:
    """The child's entry point (``child.run_child``)."""
    child.run_child(_serve)


class PerceptionProcess:
    """The parent's handle: start the child, poll its block, reset, stop (a ``PerceptionWorker``)."""

    START_TIMEOUT_S = 120.0  # importing OpenCV and filterpy on a loaded machine (before torque)
    STOP_TIMEOUT_S = 5.0

    def __init__(self, job: PerceptionJob) -> None:
        self.job = job
        self.names = job.tracker().names  # checks the layout here, in one line, not in the child
        self._n = _block_len(len(self.names))
        self._ring, self._objects, self._ctl = _layout(len(self.names))
        self._shm: child.SharedBlock | None = None
        self._block: np.ndarray | None = None
        self._child: child.ChildProcess | None = None
        self._plates_read = 0
        self._last: np.ndarray | None = None
        self._frames: Any = None  # the frame block, opened here only if a pair is asked for

    @property
    def pid(self) -> int | None:
        return None if self._child is None else self._child.pid

    def start(self) -> None:
        """Start the child and wait until it serves."""
        self._shm = child.SharedBlock(8 * self._n)
        self._block = self._shm.array(self._n)
        self._block[:] = 0.0
        self._block[_EPOCH] = -1.0
        self._block[self._ctl + _CTL_RESET] = -math.inf
        self._child = child.ChildProcess(
            "perception process", "sim2real.deploy.perception_process",
            (self.job, self._shm.name), start_timeout_s=self.START_TIMEOUT_S,
            stop_timeout_s=self.STOP_TIMEOUT_S, nice=self.job.nice,
        )  # fmt: skip
        try:
            self._child.start()
        except BaseException:
            self.close()
            raise

    def death(self) -> str | None:
        """One line saying how the child died, or None while it lives."""
        return None if self._child is None else self._child.death()

    def check_alive(self) -> None:
        if self._child is not None:
            self._child.check_alive()

    def reset(self, epoch: int, reset_s: float) -> None:
        assert self._block is not None
        self._block[self._ctl + _CTL_RESET] = reset_s  # before the epoch: the child reads
        self._block[self._ctl + _CTL_EPOCH] = epoch  # the epoch first

    def poll(self) -> tuple[Snapshot, list[PlateMeasurement]]:
        self.check_alive()
        if self._block is None:
            raise HardwareError("the perception process is not running")
        view = self._block[: self._ctl]
        block = child.read_consistent(view, view.copy, _LOCK)
        if block is None:  # the writer was preempted mid-write: the previous state is whole
            block = self._last
        if block is None:
            return Snapshot(-1, -1, -math.inf, {}, False, 0), []
        self._last = block
        written = int(block[_PLATES])
        plates: list[PlateMeasurement] = []
        for n in range(max(self._plates_read, written - _RING), written):
            o = self._ring + (n % _RING) * _RING_FIELDS
            plates.append((int(block[o]), float(block[o + 1]), block[o + 2 : o + 5].copy()))
        self._plates_read = written
        tracks: dict[str, Track] = {}
        capture = float(block[_CAPTURE])
        for i, name in enumerate(self.names):
            o = self._objects + i * _OBJ_FIELDS
            if block[o] > 0.5:
                yaw = float(block[o + 8])
                est = ObjectEstimate(
                    block[o + 1 : o + 4].copy(),
                    float(block[o + 7]),
                    None if math.isnan(yaw) else yaw,
                )
                tracks[name] = Track(est, block[o + 4 : o + 7].copy(), capture)
        snap = Snapshot(
            int(block[_EPOCH]), int(block[_SEQ]), capture, tracks, block[_EE_SEEN] > 0.5,
            int(block[_PAIRS]), float(block[_SAME_SINCE]),
        )  # fmt: skip
        return snap, plates

    def pair(self) -> FramePair | None:
        """The newest pair in the frame block (video and datasets; not on the loop's path)."""
        if self._frames is None:
            self._frames = self.job.frames.open()
        pair: FramePair | None = self._frames.latest()
        return pair

    def close(self) -> None:
        """Ask the child to stop, kill it if it does not; release the block. Idempotent."""
        if self._child is not None:
            self._child.stop()
            self._child = None
        if self._frames is not None:
            self._frames.close()
            self._frames = None
        if self._shm is not None:
            self._block = None
            self._shm.close()
            self._shm = None


if __name__ == "__main__":
    main()
