"""Where the deploy loop's percepts come from: the tool, and the objects a task asks for.

``StereoPerception`` is the real pipeline on a free-running frame source: each period it takes
the newest frame pair (never waiting; a pair it has already measured is not measured again),
runs the trackers the task needs on it, and predicts every track from the pair's capture time to
the command time.

* The tool: the wrist plate (``calibration.perception.StereoMarkerTracker``) plus the
  plate-to-tool offset turned by the base yaw reading (the linkage keeps the gripper level).
  When the plate is out of view it falls back to forward kinematics of the joint readings,
  corrected by the last camera-vs-FK offset.
* Objects, by name, from one registry (``OBJECTS``): ``target`` (the target plate), ``cube``
  (``calibration.cube_tracker.StereoCubeTracker``: any of its five face markers), ``seam_start``
  and ``seam_end`` (``StereoSeamTracker``: two plates beyond the seam's ends).

``blind_s`` is the time since an object was last measured, counted in capture time (0 when the
newest pair saw it), as the env's sensor model counts it. ``OraclePerception`` reads the truth
(the ``sim`` backend): the policy still sees servo readings.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import threading
import time
import zlib
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from calibration.cube import MarkerCube, SeamMarkers
from calibration.errors import CalibrationError
from calibration.kalman import TrackerConfig
from calibration.perception import StereoMarkerTracker
from calibration.triangulate import StereoRig
from hardware.arm import ArmState
from hardware.errors import HardwareError
from hardware.spec import ArmSpec
from sim2real import scene_names as names
from sim2real.deploy.frames import FramePair, FrameSource, check_fresh_s
from sim2real.envs.contract import ObjectEstimate, Percept
from sim2real.errors import ConfigError

log = logging.getLogger(__name__)

# The target plate stands still for an episode: a quiet model that coasts through occlusion
# (the gripper covers the plate exactly when it arrives).
QUIET = TrackerConfig(
    model="cv", manoeuvre_std=None, process_std=0.001, init_velocity_std_mps=0.001, max_coast_s=3600
)


@dataclass(frozen=True)
class MarkerLayout:
    """Which markers this rig has, their ids and sizes (a YAML file for a real rig; the mock
    world's by default). ``None`` for an object that is not set up."""

    dictionary: str = names.MARKER_DICTIONARY
    ee_id: int = names.EE_MARKER_ID
    ee_size_m: float = names.EE_MARKER_SIZE_M
    ee_marker_p_tool_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    target: tuple[int, float] | None = (names.TARGET_MARKER_ID, names.TARGET_MARKER_SIZE_M)
    cube: MarkerCube | None = names.MARKER_CUBE
    seam: SeamMarkers | None = names.SEAM_MARKERS
    source: str = "the mock rig's markers"

    @classmethod
    def for_spec(cls, spec: ArmSpec) -> MarkerLayout:
        """The layout the MJCF twin uses: the wrist plate on a riser on top of the wrist link."""
        mx, my, mz = names.EE_MARKER_POS_M
        L = spec.links
        return cls(ee_marker_p_tool_m=(L.tool_forward_m - mx, -my, -L.tool_down_m - mz))

    @classmethod
    def load(cls, path: Path, spec: ArmSpec) -> MarkerLayout:
        """A YAML file with optional ``target: {id, size_m}``, ``cube: {size_m, marker_m,
        face_ids}`` and ``seam: {start_id, end_id, marker_m, end_offset_m}`` sections; a
        section left out means that object is not set up on this rig."""
        import yaml

        try:
            data = yaml.safe_load(Path(path).read_text()) or {}
        except (OSError, yaml.YAMLError) as exc:
            raise ConfigError(f"marker layout {str(path)!r}: {exc}".splitlines()[0]) from None
        if not isinstance(data, dict):
            raise ConfigError(f"marker layout {str(path)!r}: expected a mapping, got {data!r}")
        base = cls.for_spec(spec)
        try:
            target = data.get("target")
            cube = data.get("cube")
            seam = data.get("seam")
            return replace(
                base,
                target=None if target is None else (int(target["id"]), float(target["size_m"])),
                cube=None
                if cube is None
                else MarkerCube(
                    size_m=float(cube["size_m"]),
                    marker_m=float(cube["marker_m"]),
                    face_ids=tuple(int(i) for i in cube["face_ids"]),
                ),
                seam=None if seam is None else SeamMarkers(**seam),
                source=str(path),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"marker layout {str(path)!r}: bad entry ({exc})") from None

    def provides(self) -> tuple[str, ...]:
        out = []
        if self.target is not None:
            out.append("target")
        if self.cube is not None:
            out.append("cube")
        if self.seam is not None:
            out += ["seam_start", "seam_end"]
        return tuple(out)


@dataclass(frozen=True)
class Track:
    """An object's filtered estimate at a frame's capture time, and how to carry it forward."""

    estimate: ObjectEstimate  # at ``capture_s``; blind_s counted in capture time
    velocity_mps: np.ndarray
    capture_s: float

    def at(self, command_s: float) -> ObjectEstimate:
        """Predicted to the command time (at most ``MAX_PREDICT_S`` ahead: a coasting quiet
        track has no velocity worth extrapolating further)."""
        dt = min(max(command_s - self.capture_s, 0.0), MAX_PREDICT_S)
        e = self.estimate
        return ObjectEstimate(e.position_m + self.velocity_mps * dt, e.blind_s, e.yaw_rad)


MAX_PREDICT_S = 0.2
_ZERO3 = np.zeros(3)


class ObjectTracker(Protocol):
    """Tracks one or more named objects on frame pairs (in the perception thread)."""

    names: tuple[str, ...]

    def observe(self, pair: FramePair) -> dict[str, Track]:
        """Measure one new pair; the tracks of the objects seen so far."""
        ...


@dataclass(frozen=True)
class TrackerOptions:
    """How the object trackers measure, as the arm's build needs.

    ``cube_one_camera``: place the cube from one camera's view where the other sees none of it
    (depth from the printed marker size). Helpful while the arm hides the cube from a camera on
    the way down; harmful where the cameras alone judge a grasp (a gripper that reads its
    command, ``pick.held_seen``): a finger over a marker's edge moves such a fit by centimetres,
    the estimate leaves the tool, and a held cube counts as dropped (``docs/studies/pick.md``,
    section 6). So it follows the gripper's feedback kind (``for_spec``)."""

    cube_one_camera: bool = True

    @classmethod
    def for_spec(cls, spec: ArmSpec) -> TrackerOptions:
        gripper = spec.gripper
        return cls(cube_one_camera=gripper is None or gripper.feedback == "measured")


class _PlateTracker:
    names = ("target",)

    def __init__(
        self,
        rig: StereoRig,
        base_T_left: np.ndarray,
        layout: MarkerLayout,
        options: TrackerOptions = TrackerOptions(),
    ) -> None:
        assert layout.target is not None
        marker_id, size = layout.target
        self.tracker = StereoMarkerTracker(
            rig, base_T_left, marker_id, layout.dictionary, size, tracker=QUIET
        )
        self._seen_s: float | None = None

    def observe(self, pair: FramePair) -> dict[str, Track]:
        est = self.tracker.observe(pair.left_bgr, pair.right_bgr, pair.capture_s)
        if self.tracker.last_measurement is not None:
            self._seen_s = pair.capture_s
        if self._seen_s is None or not est.valid:
            return {}
        blind = max(0.0, pair.capture_s - self._seen_s)
        obj = ObjectEstimate(est.position_m, blind)
        return {"target": Track(obj, est.velocity_mps, pair.capture_s)}


class _CubeTracker:
    names = ("cube",)

    def __init__(
        self,
        rig: StereoRig,
        base_T_left: np.ndarray,
        layout: MarkerLayout,
        options: TrackerOptions = TrackerOptions(),
    ) -> None:
        from calibration.cube_tracker import StereoCubeTracker

        self.tracker = StereoCubeTracker(
            rig, base_T_left, layout.cube, single_view=options.cube_one_camera
        )

    def observe(self, pair: FramePair) -> dict[str, Track]:
        est = self.tracker.observe(pair.left_bgr, pair.right_bgr, pair.capture_s)
        if not est.valid:
            return {}
        obj = ObjectEstimate(est.position_m, est.blind_s, est.yaw_rad)
        return {"cube": Track(obj, _ZERO3, pair.capture_s)}  # a still-object model


class _SeamTracker:
    names = ("seam_start", "seam_end")

    def __init__(
        self,
        rig: StereoRig,
        base_T_left: np.ndarray,
        layout: MarkerLayout,
        options: TrackerOptions = TrackerOptions(),
    ) -> None:
        from calibration.cube_tracker import StereoSeamTracker

        self.tracker = StereoSeamTracker(rig, base_T_left, layout.seam)

    def observe(self, pair: FramePair) -> dict[str, Track]:
        est = self.tracker.observe(pair.left_bgr, pair.right_bgr, pair.capture_s)
        if not est.valid:
            return {}
        t, b = pair.capture_s, est.blind_s
        return {
            "seam_start": Track(ObjectEstimate(est.start_m, b), _ZERO3, t),
            "seam_end": Track(ObjectEstimate(est.end_m, b), _ZERO3, t),
        }


TrackerFactory = Callable[[StereoRig, np.ndarray, MarkerLayout, TrackerOptions], Any]
# object name → the tracker that provides it (one tracker may provide several names)
OBJECTS: dict[str, TrackerFactory] = {
    "target": _PlateTracker,
    "cube": _CubeTracker,
    "seam_start": _SeamTracker,
    "seam_end": _SeamTracker,
}


class Perception(Protocol):
    def reset(self) -> None: ...

    def perceive(self, state: ArmState, command_s: float) -> Percept: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class PairResult:
    """What one frame pair gave: the wrist plate's measurement and every object's track."""

    capture_s: float
    plate_m: np.ndarray | None  # the wrist plate, where this pair measured it
    tracks: dict[str, Track]
    same_since_s: float = -math.inf  # the capture time since which the images are unchanged


class PairTracker:
    """The wrist plate and the task's objects, measured and filtered pair by pair: the work of
    the perception worker, the same code in a thread and in the perception process."""

    def __init__(
        self,
        rig: StereoRig,
        base_T_left: np.ndarray,
        layout: MarkerLayout,
        objects: tuple[str, ...],
        ee_tracker: TrackerConfig,
        options: TrackerOptions = TrackerOptions(),
    ) -> None:
        self.ee = StereoMarkerTracker(
            rig, base_T_left, layout.ee_id, layout.dictionary, layout.ee_size_m, ee_tracker
        )
        self.trackers: list[ObjectTracker] = []
        made: set[TrackerFactory] = set()
        for name in objects:
            factory = OBJECTS[name]
            if factory not in made:
                made.add(factory)
                self.trackers.append(factory(rig, base_T_left, layout, options))
        # every name a tracker may report (a seam tracker reports both ends)
        self.names = tuple(n for t in self.trackers for n in t.names)
        self._digest: int | None = None
        self._same_since_s = -math.inf

    def observe(self, pair: FramePair) -> PairResult:
        digest = image_digest(pair)
        if digest != self._digest:  # a sensor's noise alone changes a live camera's image
            self._digest, self._same_since_s = digest, pair.capture_s
        self.ee.observe(pair.left_bgr, pair.right_bgr, pair.capture_s)
        meas = self.ee.last_measurement
        tracks: dict[str, Track] = {}
        for tracker in self.trackers:
            tracks.update(tracker.observe(pair))
        plate = None if meas is None else np.asarray(meas.position_m, dtype=float).copy()
        return PairResult(pair.capture_s, plate, tracks, self._same_since_s)


def image_digest(pair: FramePair, stride: int = 4) -> int:
    """A cheap fingerprint of both images (every ``stride``-th pixel): equal fingerprints on
    pairs captured while the arm moved mean the images did not change (a frozen camera)."""
    left = np.ascontiguousarray(pair.left_bgr[::stride, ::stride])
    right = np.ascontiguousarray(pair.right_bgr[::stride, ::stride])
    return zlib.crc32(right.data, zlib.crc32(left.data))


@dataclass(frozen=True)
class Snapshot:
    """What the perception worker published after its last pair (replaced whole, never
    mutated: the control loop reads it without a lock)."""

    epoch: int
    seq: int
    capture_s: float
    tracks: dict[str, Track]
    ee_seen: bool
    pairs: int  # pairs measured since the worker started
    same_since_s: float = -math.inf  # capture time since which the images are unchanged


# (epoch, capture time, the wrist plate's position): each measurement of the plate, in order
PlateMeasurement = tuple[int, float, np.ndarray]
_EMPTY = Snapshot(-1, -1, -math.inf, {}, False, 0)


class PerceptionWorker(Protocol):
    """Runs a ``PairTracker`` on the newest pairs, off the control loop (a thread or a
    process); the loop polls what it published and never waits for it."""

    def start(self) -> None: ...

    def reset(self, epoch: int, reset_s: float) -> None:
        """New tracks from the first pair captured at or after ``reset_s``, tagged ``epoch``."""
        ...

    def poll(self) -> tuple[Snapshot, list[PlateMeasurement]]:
        """The newest snapshot and the plate measurements since the last poll; raises
        ``HardwareError`` (one line) when the worker died."""
        ...

    def pair(self) -> FramePair | None:
        """The pair the worker measured last, if it can be had in this process."""
        ...

    def close(self) -> None: ...


class ThreadWorker:
    """The worker as a thread of the control process, at ``nice`` where Linux allows a thread's
    own niceness. For frame sources that live in this process (OpenCV capture threads, a test's
    frames); OpenCV releases the GIL while it detects, but the Python around it does not."""

    def __init__(
        self, frames: FrameSource, make_tracker: Callable[[], PairTracker], nice: int
    ) -> None:
        self.frames, self._make, self._nice = frames, make_tracker, nice
        self._snapshot = _EMPTY
        self._plates: deque[PlateMeasurement] = deque()
        self._epoch, self._reset_s = 0, -math.inf
        self._error: BaseException | None = None
        self._running = False
        self._thread: threading.Thread | None = None
        self._wake = threading.Event()
        self._last_pair: FramePair | None = None

    def start(self) -> None:
        self._running = True
        self._thread = threading.Thread(target=self._work, name="perception", daemon=True)
        self._thread.start()

    def _work(self) -> None:
        with contextlib.suppress(OSError, AttributeError):  # Linux: per-thread nice
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), self._nice)
        epoch, seq, pairs = -1, -1, 0
        tracker = self._make()
        try:
            while self._running:
                pair = self.frames.latest()
                if self._epoch != epoch:  # reset() asked for fresh tracks
                    epoch = self._epoch
                    tracker, seq = self._make(), -1
                if pair is None or pair.seq == seq or pair.capture_s < self._reset_s:
                    # nothing new, or a frame from before the objects were placed anew
                    self._wake.wait(0.005)
                    self._wake.clear()
                    continue
                seq = pair.seq
                result = tracker.observe(pair)
                self._last_pair = pair
                pairs += 1
                if epoch == self._epoch:  # not reset meanwhile
                    if result.plate_m is not None:
                        self._plates.append((epoch, result.capture_s, result.plate_m))
                    self._snapshot = Snapshot(
                        epoch, seq, result.capture_s, result.tracks, result.plate_m is not None,
                        pairs, result.same_since_s,
                    )  # fmt: skip
        except BaseException as exc:  # surfaced by poll(): perception must not die silently
            self._error = exc

    def reset(self, epoch: int, reset_s: float) -> None:
        self._reset_s = reset_s
        self._epoch = epoch
        self._wake.set()

    def poll(self) -> tuple[Snapshot, list[PlateMeasurement]]:
        if self._error is not None:
            first = (str(self._error).splitlines() or [type(self._error).__name__])[0]
            raise HardwareError(f"perception stopped: {first}") from self._error
        if self._thread is None:
            raise ConfigError("StereoPerception.perceive() before start()")
        plates = []
        while self._plates:
            plates.append(self._plates.popleft())
        return self._snapshot, plates

    def pair(self) -> FramePair | None:
        return self._last_pair

    def close(self) -> None:
        self._running = False
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None


WORKERS = ("auto", "thread", "process")


class StereoPerception:
    """The wrist plate plus the task's objects, tracked on a free-running stereo source.

    Detection, triangulation and filtering run off the control loop (``start``), as capture
    does, so a slow pair never delays a command. Where the frames are in shared memory (the
    mock's render process) they run in their own process (``perception_process``): a thread
    of this process would hold its GIL, and a worker preempted by the machine's load while
    holding it keeps the real-time loop waiting after its wake-up. Elsewhere (OpenCV capture
    threads) in a thread. The control loop's ``perceive`` only reads the newest snapshot and
    predicts it to the command time.

    The tool estimate is forward kinematics of the fresh joint readings, corrected by what the
    cameras saw: the wrist plate against FK at the frame's capture time. So it carries no camera
    latency, and the camera still removes the spec's geometry errors near the current pose.
    """

    BIAS_GAIN = 0.3  # per measured pair: the correction settles within a few frames
    WORKER_NICE = 5  # the control loop wins the core when both are runnable
    # The wrist plate's gate: a plate measurement whose tool disagrees with forward kinematics
    # (as corrected so far) by more than this is a false detection (a marker decoded where the
    # plate is not, a bad stereo match): rejected, counted, logged, never fed to the
    # correction. Above what the correction absorbs between two frames (triangulation noise of
    # a few mm, the readings' interpolation to the capture time while moving) and below a
    # false detection's error; a spec whose geometry is off by more than this never gets a
    # plate accepted, and the blind limit stops the run saying so.
    PLATE_GATE_M = 0.04
    # Frozen cameras: the same image for this long while the joints moved this far (a live
    # camera's image changes with its noise alone; a still rendered scene may repeat exactly,
    # so a still arm proves nothing).
    FROZEN_LIMIT_S = 1.0
    FROZEN_MOTION_RAD = 0.05

    def __init__(
        self,
        frames: FrameSource,
        rig: StereoRig,
        base_T_left: np.ndarray,
        spec: ArmSpec,
        objects: tuple[str, ...],
        layout: MarkerLayout | None = None,
        tracker: TrackerConfig | None = None,
        yaw_sign: float = 1.0,
        worker: str = "auto",
        plate_gate_m: float | None = None,
    ) -> None:
        self.frames, self.rig, self.spec = frames, rig, spec
        gate = self.PLATE_GATE_M if plate_gate_m is None else float(plate_gate_m)
        if not (math.isfinite(gate) and gate > 0.0):
            raise ConfigError(f"plate_gate_m {plate_gate_m!r} must be a finite distance > 0")
        self.plate_gate_m = gate
        self.layout = layout or MarkerLayout.for_spec(spec)
        unknown = [o for o in objects if o not in OBJECTS]
        if unknown:
            raise ConfigError(f"no tracker for object(s) {unknown}; known: {sorted(OBJECTS)}")
        missing = [o for o in objects if o not in self.layout.provides()]
        if missing:
            raise ConfigError(
                f"the policy's task needs {', '.join(missing)}, but the marker layout "
                f"({self.layout.source}) has no such marker set up"
            )
        if worker not in WORKERS:
            raise ConfigError(f"perception worker {worker!r}; valid: {list(WORKERS)}")
        if worker == "auto":
            worker = "process" if hasattr(frames, "share") else "thread"
        if worker == "process" and not hasattr(frames, "share"):
            raise ConfigError(
                f"a perception process needs frames in shared memory; {type(frames).__name__} "
                "has none (use worker='thread')"
            )
        self.worker_kind = worker
        self.objects = objects
        self.options = TrackerOptions.for_spec(spec)  # what this build's cameras must judge
        self.base_T_left = np.asarray(base_T_left, dtype=float)
        cfg = tracker or TrackerConfig()
        self._ee_cfg = replace(cfg, max_coast_s=min(cfg.max_coast_s, 0.1))
        self._offset = np.asarray(self.layout.ee_marker_p_tool_m, dtype=float)
        self._yaw_sign = spec.joints[0].sign * yaw_sign
        # "plate_rejected": plate measurements outside the gate (false detections)
        self.detections = {
            "pairs": 0, "periods": 0, "ee": 0, "fk_fallback": 0, "reused": 0, "plate_rejected": 0,
        }  # fmt: skip
        self._plate_seen_s = -math.inf  # capture time of the last accepted plate (or the reset)
        self._rejecting = 0  # plate measurements rejected in a row
        self._last_rejected = False
        self._q_hist: deque[tuple[float, np.ndarray]] = deque(maxlen=400)  # ~20 s at 20 Hz
        self._epoch = 0
        self._snapshot = _EMPTY
        self._bias = np.zeros(3)
        self._bias_n = 0
        self._worker: PerceptionWorker | None = None

    def new_tracker(self) -> PairTracker:
        return PairTracker(
            self.rig, self.base_T_left, self.layout, self.objects, self._ee_cfg, self.options
        )

    @property
    def last_pair(self) -> FramePair | None:
        """The pair perception measured last (a process worker's: the newest in the block)."""
        return None if self._worker is None else self._worker.pair()

    @property
    def last_frames(self) -> tuple[np.ndarray, np.ndarray] | None:
        p = self.last_pair
        return None if p is None else (p.left_bgr, p.right_bgr)

    @property
    def ee_seen(self) -> bool:
        """The last percept's tool came from the wrist marker (False: forward kinematics, or a
        plate measurement the gate rejected)."""
        return self._snapshot.ee_seen and not self._last_rejected

    @property
    def worker_pid(self) -> int | None:
        """The perception process's pid (None for a thread worker)."""
        return getattr(self._worker, "pid", None)

    def check_frames(self, pair: FramePair) -> None:
        """The calibration must be for the resolution the cameras deliver (before moving)."""
        for name, img, cam in (
            ("left", pair.left_bgr, self.rig.left),
            ("right", pair.right_bgr, self.rig.right),
        ):
            size = (img.shape[1], img.shape[0])
            if size != tuple(cam.image_size):
                raise CalibrationError(
                    f"the {name} camera delivers {size[0]}x{size[1]} frames but the stereo "
                    f"calibration is for {cam.image_size[0]}x{cam.image_size[1]}: "
                    "recalibrate at this resolution or set the camera to it"
                )

    def start(self) -> None:
        """Start the worker (a process: start-up, before torque is on, may take seconds)."""
        if self.worker_kind == "process":
            from sim2real.deploy.perception_process import PerceptionJob, PerceptionProcess

            job = PerceptionJob(
                frames=self.frames.share(),  # type: ignore[attr-defined]
                rig=self.rig,
                base_T_left=self.base_T_left,
                layout=self.layout,
                objects=self.objects,
                ee_tracker=self._ee_cfg,
                options=self.options,
                nice=self.WORKER_NICE,
            )
            self._worker = PerceptionProcess(job)
        else:
            self._worker = ThreadWorker(self.frames, self.new_tracker, self.WORKER_NICE)
        self._worker.start()
        self._plate_seen_s = time.monotonic()

    def _q_at(self, t_s: float) -> np.ndarray | None:
        """The joint readings interpolated linearly to ``t_s`` (None: no reading from around
        then). Searched from the newest reading back: capture times are a few periods old, and
        this runs in the control loop for every object and plate (copying the whole history
        into arrays cost ~0.15 ms a call)."""
        hist = self._q_hist
        if not hist or not hist[0][0] <= t_s <= hist[-1][0] + 0.1:
            return None
        t_new, q_new = hist[-1]
        if t_s >= t_new:
            return q_new.copy()
        for t_old, q_old in reversed(hist):
            if t_old <= t_s:
                if t_old == t_s:
                    return q_old.copy()
                slope = (q_new - q_old) / (t_new - t_old)
                return np.asarray(slope * (t_s - t_old) + q_old, dtype=float)
            t_new, q_new = t_old, q_old
        return None  # unreachable: the oldest reading is at or before t_s

    def _tool_at(self, t_s: float) -> np.ndarray | None:
        """The tool's estimate at ``t_s`` (the capture time of an object's newest frame): forward
        kinematics of the readings then, with the current plate correction (None: no reading
        from around then)."""
        q = self._q_at(t_s)
        if q is None:
            return None
        return np.asarray(self.spec.forward_kinematics(q) + self._bias, dtype=float)

    def _plate_error(self, plate_m: np.ndarray, capture_s: float) -> np.ndarray | None:
        """The camera measures the tool late but without the spec's geometry errors; the joint
        readings are fresh. The plate's tool against forward kinematics of the readings at the
        capture time (None: no reading from around the capture time, the first frames)."""
        q_cap = self._q_at(capture_s)
        if q_cap is None:
            return None
        yaw = self._yaw_sign * float(q_cap[0])
        c, s = math.cos(yaw), math.sin(yaw)
        dx, dy, dz = self._offset
        tool = plate_m + np.array([c * dx - s * dy, s * dx + c * dy, dz])
        return np.asarray(tool - self.spec.forward_kinematics(q_cap), dtype=float)

    def _plate(self, plate_m: np.ndarray, capture_s: float) -> None:
        """One plate measurement through the gate: inside it, the correction (the slowly
        varying camera-vs-FK difference) moves by ``BIAS_GAIN`` of it (the run's first sample
        is taken whole); outside, it is rejected, counted and logged (the first of a run of
        rejections, and the plate's return), and the tool stays on FK."""
        error = self._plate_error(plate_m, capture_s)
        if error is None:
            return
        jump_m = float(np.linalg.norm(error - self._bias))
        if jump_m > self.plate_gate_m:
            self.detections["plate_rejected"] += 1
            self._last_rejected = True
            if self._rejecting == 0:
                log.warning(
                    "wrist plate rejected: %.3f m from forward kinematics (gate %.3f m); the "
                    "tool stays on FK",
                    jump_m,
                    self.plate_gate_m,
                )
            self._rejecting += 1
            return
        if self._rejecting:
            log.info("wrist plate accepted again after %d rejected", self._rejecting)
        self._rejecting, self._last_rejected = 0, False
        self._bias_n += 1
        self._bias = (
            error if self._bias_n == 1 else self._bias + self.BIAS_GAIN * (error - self._bias)
        )
        self._plate_seen_s = max(self._plate_seen_s, capture_s)
        self.detections["ee"] += 1

    def _check_not_frozen(self, snap: Snapshot) -> None:
        """Images unchanged for ``FROZEN_LIMIT_S`` of capture time while the joints moved
        ``FROZEN_MOTION_RAD``: the camera repeats a frame under fresh timestamps."""
        still_s = snap.capture_s - snap.same_since_s
        if not (math.isfinite(still_s) and still_s > self.FROZEN_LIMIT_S):
            return
        q_then = self._q_at(snap.same_since_s)
        if q_then is None and self._q_hist:
            q_then = self._q_hist[0][1]  # frozen since before the oldest reading kept
        q_now = self._q_at(snap.capture_s)
        if q_then is None or q_now is None:
            return
        moved = float(np.max(np.abs(q_now - q_then)))
        if moved > self.FROZEN_MOTION_RAD:
            raise HardwareError(
                f"cameras frozen: the same image for {still_s:.2f} s while the joints moved "
                f"{moved:.2f} rad (limit {self.FROZEN_LIMIT_S:.1f} s)"
            )

    # ---- the control loop's side ------------------------------------------------------------
    def reset(self) -> None:
        """New episode: the objects were placed anew. Tracks restart from the next pair, and
        the first plate measurement replaces the FK correction."""
        self._epoch += 1
        self._plate_seen_s = time.monotonic()
        self._rejecting, self._last_rejected = 0, False
        if self._worker is not None:
            self._worker.reset(self._epoch, time.monotonic())

    def _newest_capture_s(self) -> float | None:
        """The source's newest capture time, without copying a frame where it can."""
        newest = getattr(self.frames, "newest_capture_s", None)
        if newest is not None:
            value = newest()
            return None if value is None else float(value)
        pair = self.frames.latest()
        return None if pair is None else pair.capture_s

    def perceive(self, state: ArmState, command_s: float) -> Percept:
        if self._worker is None:
            raise ConfigError("StereoPerception.perceive() before start()")
        snap, plates = self._worker.poll()  # raises when the worker died
        q_now = np.asarray(state.positions_rad[: self.spec.n_joints], dtype=float)
        self._q_hist.append((command_s, q_now))
        capture_s = self._newest_capture_s()
        if capture_s is None:
            raise ConfigError("perceive() before the cameras delivered a frame (start them first)")
        check_fresh_s(self.frames, capture_s, command_s)
        for epoch, t_s, plate_m in plates:
            if epoch == self._epoch:
                self._plate(plate_m, t_s)
        self.detections["periods"] += 1
        self.detections["pairs"] = snap.pairs
        if snap.epoch != self._epoch:  # nothing measured since the reset yet
            snap = Snapshot(self._epoch, -1, -math.inf, {}, False, snap.pairs)
        self._check_not_frozen(snap)
        self._snapshot = snap
        ee = self.spec.forward_kinematics(q_now) + self._bias
        if not self.ee_seen:
            self.detections["fk_fallback"] += 1
        objects = {
            name: replace(
                track.at(command_s),
                tool_then_m=self._tool_at(track.capture_s),
            )
            for name, track in snap.tracks.items()
        }
        tool_blind_s = max(0.0, max(capture_s, snap.capture_s) - self._plate_seen_s)
        return Percept(ee, objects, tool_blind_s)

    def close(self) -> None:
        if self._worker is not None:
            self._worker.close()
            self._worker = None
        # the frame source belongs to whoever opened it (the world, or the backend's stack)


class OraclePerception:
    """The truth of a world that has one (the ``sim`` backend), nothing hidden."""

    def __init__(self, truth: Callable[[], tuple[np.ndarray, dict[str, np.ndarray]]]) -> None:
        self._truth = truth

    def reset(self) -> None:
        """Stateless."""

    def perceive(self, state: ArmState, command_s: float) -> Percept:
        tool, objects = self._truth()
        return Percept(
            np.array(tool), {k: ObjectEstimate(np.array(v), 0.0) for k, v in objects.items()}
        )

    def close(self) -> None:
        """Nothing to release."""
