"""Perception in its own process: real rendered frames (MuJoCo), real OpenCV detection, the
frames and the estimates in shared memory, a real child process.

Nothing here depends on a rate or a period: each frame pair is published and then waited for
(bounds far above what a loaded machine needs; a stuck child fails them instead of hanging).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from timescale import scaled  # type: ignore[import-not-found]

from hardware.arm import ArmState
from hardware.errors import HardwareError
from hardware.spec import ArmSpec
from sim2real import scene_names as names
from sim2real.deploy.perception import StereoPerception
from sim2real.deploy.perception_process import PerceptionJob, PerceptionProcess
from sim2real.deploy.policy_io import PolicyIO
from sim2real.deploy.render_process import FrameBlock, SharedFrames
from sim2real.deploy.virtual_cameras import VirtualStereoCameras, stereo_rig_of

from .children import assert_dies_with_its_host, kill_mid_deploy  # type: ignore[import-not-found]

BOUND_S = scaled(60.0)


@pytest.fixture(scope="module")
def rendered(spec: ArmSpec) -> Iterator[tuple[VirtualStereoCameras, list[tuple[np.ndarray, Any]]]]:
    """A short pick-scene clip: the arm sweeping over a placed cube, with the target plate."""
    cams = VirtualStereoCameras(spec, scene="pick")
    a = int(cams.model.joint(names.CUBE_JOINT).qposadr[0])
    cams.data.qpos[a : a + 3] = (0.16, 0.03, 0.0125)
    cams.data.qpos[a + 3 : a + 7] = (math.cos(0.2), 0.0, 0.0, math.sin(0.2))
    clip = []
    home = spec.actuator_home_rad
    for i in range(12):
        q = home.copy()
        q[0] += 0.15 * math.sin(i / 3.0)
        q[1] += 0.05 * math.cos(i / 4.0)
        cams.pose(q, np.array([0.12, -0.10, 0.06]))
        clip.append((q, cams.read()))
    yield cams, clip
    cams.close()


def _perception(
    spec: ArmSpec, cams: VirtualStereoCameras, frames: FrameBlock, worker: str
) -> StereoPerception:
    rig, base_T_left = stereo_rig_of(cams.rig)
    return StereoPerception(frames, rig, base_T_left, spec, ("target", "cube"), worker=worker)


def _wait_for(p: StereoPerception, state: ArmState, command_s: float, seq: int) -> object:
    """perceive() until the worker has measured pair ``seq``."""
    deadline = time.monotonic() + BOUND_S
    while True:
        percept = p.perceive(state, command_s)
        if p._snapshot.seq == seq:
            return percept
        assert time.monotonic() < deadline, f"pair {seq} was never measured ({p.worker_kind})"
        time.sleep(0.002)


def test_the_process_estimates_equal_the_thread_version_on_the_same_frames(
    spec: ArmSpec, rendered: tuple[VirtualStereoCameras, list[tuple[np.ndarray, Any]]]
) -> None:
    cams, clip = rendered
    frames = FrameBlock(cams.height, cams.width, timeout_s=1e6)  # no freshness test here
    threaded = _perception(spec, cams, frames, "thread")
    process = _perception(spec, cams, frames, "process")
    assert process.worker_kind == "process" and threaded.worker_kind == "thread"
    try:
        threaded.start()
        process.start()
        assert process.worker_pid not in (None, os.getpid())
        for p in (threaded, process):
            p.reset()
        t0 = time.monotonic()  # capture times after the reset: older pairs are skipped
        seen = {"ee": 0, "cube": 0, "target": 0}
        for i, (q, pair) in enumerate(clip):
            capture_s = t0 + i / 30.0
            frames.publish(pair.left_bgr, pair.right_bgr, capture_s)
            state = ArmState(positions_rad=q, timestamp_s=capture_s)
            command_s = capture_s + 0.01
            a = _wait_for(threaded, state, command_s, i + 1)
            b = _wait_for(process, state, command_s, i + 1)
            np.testing.assert_allclose(b.tool_m, a.tool_m, atol=1e-12)  # type: ignore[attr-defined]
            assert b.objects.keys() == a.objects.keys()  # type: ignore[attr-defined]
            for name, est in a.objects.items():  # type: ignore[attr-defined]
                other = b.objects[name]  # type: ignore[attr-defined]
                np.testing.assert_allclose(other.position_m, est.position_m, atol=1e-12)
                assert other.blind_s == pytest.approx(est.blind_s, abs=1e-12)
                assert (other.yaw_rad is None) == (est.yaw_rad is None)
                if est.yaw_rad is not None:
                    assert other.yaw_rad == pytest.approx(est.yaw_rad, abs=1e-12)
                seen[name] += 1
            assert threaded.ee_seen == process.ee_seen
            seen["ee"] += int(process.ee_seen)
        # the clip exercised every path: the plate correction and both objects' tracks
        assert seen["ee"] >= 6 and seen["cube"] >= 6 and seen["target"] >= 6, seen
        assert threaded.detections["ee"] == process.detections["ee"] > 0
        # a reset drops the tracks until a pair captured after it is measured
        process.reset()
        state = ArmState(positions_rad=clip[-1][0], timestamp_s=time.monotonic())
        assert process.perceive(state, time.monotonic()).objects == {}
    finally:
        threaded.close()
        process.close()
        frames.close()


def test_a_child_that_cannot_start_says_why_in_one_line(
    spec: ArmSpec, rendered: tuple[VirtualStereoCameras, list[tuple[np.ndarray, Any]]]
) -> None:
    cams, _ = rendered
    rig, base_T_left = stereo_rig_of(cams.rig)
    p = StereoPerception(FrameBlock(4, 4), rig, base_T_left, spec, ("cube",))
    job = PerceptionJob(
        frames=SharedFrames("no_such_block_s2r", 480, 640, 1.0), rig=rig,
        base_T_left=base_T_left, layout=p.layout, objects=("cube",), ee_tracker=p._ee_cfg,
    )  # fmt: skip
    proc = PerceptionProcess(job)
    with pytest.raises(HardwareError) as info:
        proc.start()
    message = str(info.value)
    assert message.startswith("the perception process died (exit 3): FileNotFoundError"), message
    assert "\n" not in message
    assert proc.pid is None  # closed: nothing left running


_HOST = """
import sys
import numpy as np
from hardware.spec import load_spec
from sim2real.deploy.perception import StereoPerception
from sim2real.deploy.render_process import FrameBlock
from sim2real.deploy.virtual_cameras import stereo_rig_of
from sim2real.model import RigSpec
spec = load_spec()
rig, base_T_left = stereo_rig_of(RigSpec())
frames = FrameBlock(480, 640)
p = StereoPerception(frames, rig, base_T_left, spec, ("cube",), worker="process")
p.start()
print(p.worker_pid, flush=True)
sys.stdin.read()  # until killed
"""


@pytest.mark.realtime
def test_the_perception_process_dies_when_its_host_is_killed() -> None:
    assert_dies_with_its_host(_HOST, "perception process")


@pytest.mark.realtime
def test_a_crash_of_the_perception_process_stops_the_run_in_one_line_and_keeps_the_log(
    spec: ArmSpec, reach_io: PolicyIO, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    mocks: list[Any] = []
    message = kill_mid_deploy(
        spec, reach_io, tmp_path / "crash.npz", monkeypatch,
        lambda session: session.perception.worker_pid, seen=mocks,
    )  # fmt: skip
    assert message == "the perception process died (killed by SIGKILL)", message
    # the safe stop: the device's last torque command was torque off
    torque = mocks[0].applied("torque")
    assert torque and not any(torque[-1].applied), torque[-1]
