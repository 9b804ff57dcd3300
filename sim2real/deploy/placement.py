"""Placements the rig can see: a world that places objects puts them where its cameras find them.

A person setting up a real arm draws the seam where the cameras see both of its end plates. The
sim and mock worlds draw from the env's own distribution, and some of its seams end right at the
arm: the end plate then lies under the arm's base, or so far and so flat that one camera cannot
decode it, and no park pose reveals it. ``RigSight`` renders a candidate placement from the
rig's two virtual cameras, with the arm at home (where every episode starts), and runs the same
trackers as ``StereoPerception`` on that one frame pair. A task opts in through its contract
(``DeployContract.placed_in_view``); the loop then draws again until the rig sees every object.
"""

from __future__ import annotations

import time

import numpy as np

from calibration.markers import ArucoMarkerDetector
from hardware.spec import ArmSpec
from sim2real.camera_rig import RigSpec
from sim2real.deploy.frames import FramePair
from sim2real.deploy.perception import OBJECTS, MarkerLayout, TrackerOptions
from sim2real.deploy.virtual_cameras import VirtualStereoCameras, stereo_rig_of
from sim2real.deploy.worlds import SceneObjects


class RigSight:
    """Which of a placement's objects the rig's cameras would not find from the home pose."""

    def __init__(
        self,
        spec: ArmSpec,
        scene: str,
        objects: tuple[str, ...],
        rig: RigSpec | None = None,
        layout: MarkerLayout | None = None,
    ) -> None:
        self.spec, self.objects = spec, objects
        self.cameras = VirtualStereoCameras(spec, rig, scene)
        self.scene = SceneObjects(self.cameras.model, self.cameras.rig)
        self.stereo, self.base_T_left = stereo_rig_of(self.cameras.rig)
        self.layout = layout or MarkerLayout.for_spec(spec)
        self._seq = 0

    @classmethod
    def for_task(cls, spec: ArmSpec, task: str, objects: tuple[str, ...]) -> RigSight:
        """The default rig (what the sim and mock worlds build) looking at ``task``'s scene."""
        from sim2real.envs import TASKS

        return cls(spec, TASKS[task].scene, objects, RigSpec())

    def unseen(self, placement: dict[str, np.ndarray]) -> str | None:
        """None when both cameras find every object of ``placement`` (arm at home), else which
        ones they miss. Fresh trackers each call: one pair is all a decision needs."""
        self.scene.place(self.cameras.data, placement)
        self.cameras.pose(self.spec.actuator_home_rad, None)
        frames = self.cameras.read()
        self._seq += 1
        pair = FramePair(frames.left_bgr, frames.right_bgr, time.monotonic(), self._seq)
        seen: set[str] = set()
        trackers = {OBJECTS[name] for name in self.objects}
        options = TrackerOptions.for_spec(self.spec)  # as the deploy's perception measures
        for factory in trackers:
            tracker = factory(self.stereo, self.base_T_left, self.layout, options)
            seen |= set(tracker.observe(pair))
        missing = [name for name in self.objects if name not in seen]
        if not missing:
            return None
        detector = ArucoMarkerDetector(self.layout.dictionary)
        ids = [
            sorted(m.id for m in detector.detect(img)) for img in (pair.left_bgr, pair.right_bgr)
        ]
        return (
            f"the rig's cameras do not find {', '.join(missing)} from the home pose "
            f"(markers decoded: left {ids[0]}, right {ids[1]})"
        )

    def close(self) -> None:
        self.cameras.close()
