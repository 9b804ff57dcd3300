"""The wrist plate's gate and the frozen-camera check, on real rendered frames (MuJoCo), real
ArUco detection and triangulation, and the real perception worker thread.

Each pair is published and then waited for (bounds far above what a loaded machine needs), and
every capture time is set by the test: nothing depends on a rate."""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator

import numpy as np
import pytest
from timescale import scaled  # type: ignore[import-not-found]

from hardware.arm import ArmState
from hardware.errors import HardwareError
from hardware.spec import ArmSpec
from sim2real.deploy.frames import FramePair
from sim2real.deploy.perception import StereoPerception, image_digest
from sim2real.deploy.render_process import FrameBlock
from sim2real.deploy.virtual_cameras import VirtualStereoCameras, stereo_rig_of
from sim2real.errors import ConfigError

BOUND_S = scaled(60.0)


@pytest.fixture(scope="module")
def cams(spec: ArmSpec) -> Iterator[VirtualStereoCameras]:
    c = VirtualStereoCameras(spec, scene="reach")
    yield c
    c.close()


def _shot(cams: VirtualStereoCameras, q: np.ndarray) -> FramePair:
    cams.pose(q, np.array([0.12, -0.10, 0.06]))
    return cams.read()  # type: ignore[return-value]


def _perceive(p: StereoPerception, frames: FrameBlock, pair: FramePair, q: np.ndarray,
              t_s: float) -> object:  # fmt: skip
    """Publish one pair captured at ``t_s`` and perceive until the worker measured it."""
    frames.publish(pair.left_bgr, pair.right_bgr, t_s)
    want = int(frames.header[7])  # pairs published: the worker's seq for this one
    deadline = time.monotonic() + BOUND_S
    while True:
        state = ArmState(positions_rad=q, timestamp_s=t_s)
        percept = p.perceive(state, t_s + 0.005)
        if p._snapshot.seq == want:
            return percept
        assert time.monotonic() < deadline, f"pair {want} was never measured"
        time.sleep(0.002)


@pytest.fixture
def perception(
    spec: ArmSpec, cams: VirtualStereoCameras
) -> Iterator[tuple[StereoPerception, FrameBlock]]:
    frames = FrameBlock(cams.height, cams.width, timeout_s=1e6)  # no freshness test here
    rig, base_T_left = stereo_rig_of(cams.rig)
    p = StereoPerception(frames, rig, base_T_left, spec, ("target",), worker="thread")
    p.start()
    p.reset()
    try:
        yield p, frames
    finally:
        p.close()
        frames.close()


def test_a_false_plate_jump_is_rejected_counted_and_logged_and_the_tool_stays_put(
    spec: ArmSpec, cams: VirtualStereoCameras,
    perception: tuple[StereoPerception, FrameBlock], caplog: pytest.LogCaptureFixture,
) -> None:  # fmt: skip
    p, frames = perception
    q = spec.actuator_home_rad.copy()
    t0 = time.monotonic()
    for i in range(4):  # the plate where FK says: accepted
        tool = _perceive(p, frames, _shot(cams, q), q, t0 + i / 30).tool_m  # type: ignore[attr-defined]
    assert p.detections["ee"] >= 3 and p.detections["plate_rejected"] == 0 and p.ee_seen
    # the cameras see the plate where the arm is not (drawn turned 0.4 rad about the base)
    ghost = q.copy()
    ghost[0] += 0.4
    with caplog.at_level(logging.WARNING, logger="sim2real.deploy.perception"):
        for i in range(4, 8):
            jumped = _perceive(p, frames, _shot(cams, ghost), q, t0 + i / 30)
    assert p.detections["plate_rejected"] == 4 and not p.ee_seen
    np.testing.assert_allclose(jumped.tool_m, tool, atol=1e-9)  # type: ignore[attr-defined]
    said = [r.getMessage() for r in caplog.records if "wrist plate rejected" in r.getMessage()]
    assert len(said) == 1 and f"gate {p.plate_gate_m:.3f} m" in said[0]  # one line per spell
    # the tool has been unconfirmed since the last accepted plate (capture time)
    assert jumped.tool_blind_s == pytest.approx(4 / 30, abs=1e-6)  # type: ignore[attr-defined]
    back = _perceive(p, frames, _shot(cams, q), q, t0 + 8 / 30)
    assert p.ee_seen and back.tool_blind_s == 0.0  # type: ignore[attr-defined]


def test_a_plate_gate_that_is_not_a_distance_is_refused(
    spec: ArmSpec, cams: VirtualStereoCameras
) -> None:
    rig, base_T_left = stereo_rig_of(cams.rig)
    frames = FrameBlock(4, 4)
    try:
        with pytest.raises(ConfigError, match=r"plate_gate_m -0\.1 must be"):
            StereoPerception(frames, rig, base_T_left, spec, ("target",), plate_gate_m=-0.1)
    finally:
        frames.close()


def test_frozen_frames_with_fresh_timestamps_stop_once_the_arm_has_moved(
    spec: ArmSpec, cams: VirtualStereoCameras, perception: tuple[StereoPerception, FrameBlock]
) -> None:
    p, frames = perception
    q = spec.actuator_home_rad.copy()
    stuck = _shot(cams, q)
    t0 = time.monotonic()
    limit = p.FROZEN_LIMIT_S
    # the arm holds still: the same image is what a still scene looks like, not a fault
    for i in range(4):
        _perceive(p, frames, stuck, q, t0 + i * limit)
    # the arm moves and the image does not: frozen
    with pytest.raises(HardwareError, match=r"cameras frozen: the same image for .* while the "
                       r"joints moved .* rad \(limit 1\.0 s\)"):  # fmt: skip
        for i in range(4, 8):
            moved = q.copy()
            moved[0] += 0.1 * (i - 3)
            _perceive(p, frames, stuck, moved, t0 + i * limit)


def test_the_image_digest_sees_one_changed_pixel_block(
    spec: ArmSpec, cams: VirtualStereoCameras
) -> None:
    pair = _shot(cams, spec.actuator_home_rad)
    other = pair.right_bgr.copy()
    other[100:104, 200:204] += 1
    assert image_digest(pair) == image_digest(
        FramePair(pair.left_bgr.copy(), pair.right_bgr, 9.0, 2)
    )
    assert image_digest(pair) != image_digest(FramePair(pair.left_bgr, other, 1.0, 1))
