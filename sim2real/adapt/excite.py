"""The kinematic excitation ON THE ARM: the slow sweep of ``sysid.kinematics.excitation_rad``
streamed to an ``Arm`` through its safety layer, with the wrist marker seen by two cameras.

Each period logs the servo readings and what the cameras see, each with the instant it shows:
the readings the middle of their request and reply, a view the instant of its frames. The fit
(``sysid.kinematics.load_marker_log``) interpolates the readings to the views' instants. Pairing
them by period instead misreads the wrist's lag as a joint offset: the sweep moves the shoulder
at up to 0.5 rad/s, so 10 ms between a reading and its frame is 5 mrad, and a loaded host or a
camera's latency makes it tens of ms. Where the marker comes from is a ``MarkerView``:

- ``RenderedView`` (mock backend): the emulator's PHYSICAL joint angles are sampled in the loop
  (cheap) and rendered afterwards with the plant's links by the mock rig's cameras, then detected
  and triangulated (``StereoMarkerTracker``), so the rendering cost never stretches a period;
- ``CameraView`` (serial backend): the newest pair of the user's calibrated cameras, measured in
  the loop.

The log has the keys ``sysid --kinematics`` reads (``t_s`` and ``joints_rad``, ``marker_t_s`` and
``ee_marker_m`` with NaN where the marker was not seen), so a recorded excitation can be refitted
by hand.
"""

from __future__ import annotations

import time
from typing import Any, Protocol

import numpy as np

from hardware.arm import ArmBase
from hardware.spec import ArmSpec
from sim2real import model as names
from sim2real.sysid.kinematics import excitation_rad

KINEMATIC_RATE_HZ = 10.0  # the sweep is slow (periods of 7-23 s): 10 Hz samples it densely


class MarkerView(Protocol):
    def snapshot(self) -> tuple[Any, float]:
        """Called once per period, right after the joint reading: must be quick. Returns what
        the view holds and the ``time.monotonic()`` instant it shows (a frame's capture)."""
        ...

    def markers_m(self, snapshots: list[Any]) -> np.ndarray:
        """(k, 3) wrist-marker face centres in the base frame, NaN rows where not seen."""
        ...


def _tracker(stereo: Any, base_T_left: np.ndarray) -> Any:
    from calibration.perception import StereoMarkerTracker

    return StereoMarkerTracker(
        stereo,
        base_T_cam=base_T_left,
        marker_id=names.EE_MARKER_ID,
        dictionary=names.MARKER_DICTIONARY,
        marker_length_m=names.EE_MARKER_SIZE_M,
    )


class RenderedView:
    """The mock rig's cameras looking at the plant's arm (its links, its physical angles)."""

    def __init__(self, plant_spec: ArmSpec, emulator: Any, rig: Any | None = None) -> None:
        self.plant_spec = plant_spec
        self.emulator = emulator
        self.rig = rig

    def snapshot(self) -> tuple[np.ndarray, float]:
        """The plant's physical angles, sampled at once (the mock's cameras have no latency)."""
        t_ask = time.monotonic()
        physical = np.asarray(self.emulator.true_positions_rad(), dtype=float)
        return physical, 0.5 * (t_ask + time.monotonic())

    def markers_m(self, snapshots: list[Any]) -> np.ndarray:
        from sim2real.deploy.virtual_cameras import VirtualStereoCameras, stereo_rig_of

        cams = VirtualStereoCameras(self.plant_spec, self.rig)
        stereo, base_T_left = stereo_rig_of(cams.rig)
        tracker = _tracker(stereo, base_T_left)
        hidden_target = np.array([0.0, 0.6, -0.3])  # under the table, out of every view
        out = np.full((len(snapshots), 3), np.nan)
        try:
            for i, physical in enumerate(snapshots):
                cams.pose(physical, hidden_target)
                frames = cams.read()
                meas = tracker.measure(frames.left_bgr, frames.right_bgr)
                if meas is not None:
                    out[i] = meas.position_m
        finally:
            cams.close()
        return out


class CameraView:
    """A real rig: the newest frame pair of a running ``FrameSource``, measured at once."""

    def __init__(self, frames: Any, stereo: Any, base_T_left: np.ndarray) -> None:
        self.frames = frames
        self.tracker = _tracker(stereo, base_T_left)

    def snapshot(self) -> tuple[np.ndarray, float]:
        pair = self.frames.latest()
        if pair is None:
            return np.full(3, np.nan), time.monotonic()
        meas = self.tracker.measure(pair.left_bgr, pair.right_bgr)
        seen = np.full(3, np.nan) if meas is None else np.asarray(meas.position_m, dtype=float)
        return seen, pair.capture_s

    def markers_m(self, snapshots: list[Any]) -> np.ndarray:
        return np.asarray(snapshots, dtype=float).reshape(-1, 3)


def record_kinematic_excitation(
    arm: ArmBase, view: MarkerView, duration_s: float, rate_hz: float = KINEMATIC_RATE_HZ
) -> tuple[dict[str, np.ndarray], list[Any]]:
    """Home, walk to the sweep's first pose, stream the sweep, home. Returns the log (``t_s``,
    ``joints_rad`` n_joints readings, ``sent_rad``, ``marker_t_s``: the instant each snapshot
    shows) and the view's snapshots: the caller adds ``ee_marker_m = view.markers_m(snapshots)``
    (NaN where unseen) once the arm is parked, so rendering never holds a powered arm waiting."""
    spec = arm.spec
    q = excitation_rad(spec, duration_s, rate_hz)
    grip = [spec.gripper.open_rad] if spec.gripper is not None else []
    arm.home()
    arm.move_to(np.concatenate([q[0], grip]))
    keys = ("t_s", "joints_rad", "sent_rad", "marker_t_s")
    rows: dict[str, list[Any]] = {k: [] for k in keys}
    snaps: list[Any] = []
    period = 1.0 / rate_hz
    next_t = time.monotonic()
    for target in q:
        rows["sent_rad"].append(arm.command(np.concatenate([target, grip])))
        next_t += period
        time.sleep(max(0.0, next_t - time.monotonic()))
        t_ask = time.monotonic()
        state = arm.read_state()
        # the servos were sampled between the request and the reply: their middle
        rows["t_s"].append(0.5 * (t_ask + time.monotonic()))
        rows["joints_rad"].append(state.positions_rad[: spec.n_joints])
        snap, shown_s = view.snapshot()
        snaps.append(snap)
        rows["marker_t_s"].append(shown_s)
    arm.home()
    return {k: np.asarray(v, dtype=float) for k, v in rows.items()}, snaps
