"""Which views may place the cube follows the arm's build (``TrackerOptions.for_spec``): where a
gripper reads its command the cameras alone judge a grasp, and a cube placed from one camera's
view (depth from the printed marker size) is no evidence. Real MuJoCo rendering of the pick
scene, real ArUco detection on the frames."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from timescale import scaled

from calibration.perception import TrackerConfig
from hardware.arm import ArmState
from hardware.spec import PWM_SPEC_PATH, ArmSpec, load_spec
from sim2real.deploy.frames import FramePair
from sim2real.deploy.perception import PairTracker, StereoPerception, TrackerOptions
from sim2real.deploy.placement import RigSight
from sim2real.envs.contract import Percept

PWM = load_spec(PWM_SPEC_PATH)
CUBE_M = np.array([0.15, 0.0, 0.0125])


@pytest.fixture(scope="module")
def sight(spec: ArmSpec) -> Iterator[RigSight]:
    s = RigSight.for_task(spec, "pick", ("cube",))
    yield s
    s.close()


def _pair(sight: RigSight, blank_right: bool) -> FramePair:
    sight.scene.place(sight.cameras.data, {"cube": CUBE_M})
    sight.cameras.pose(sight.spec.actuator_park_rad, None)  # low, out of the cameras' way
    frames = sight.cameras.read()
    right = np.zeros_like(frames.right_bgr) if blank_right else frames.right_bgr
    return FramePair(frames.left_bgr, right, 1.0, 1)


def _cube(sight: RigSight, spec: ArmSpec, pair: FramePair) -> np.ndarray | None:
    tracker = PairTracker(sight.stereo, sight.base_T_left, sight.layout, ("cube",),
                          TrackerConfig(), TrackerOptions.for_spec(spec))  # fmt: skip
    track = tracker.observe(pair).tracks.get("cube")
    return None if track is None else np.asarray(track.estimate.position_m)


def test_the_options_follow_the_grippers_feedback(spec: ArmSpec) -> None:
    assert TrackerOptions.for_spec(spec).cube_one_camera  # measured: the gripper feels a grasp
    assert not TrackerOptions.for_spec(PWM).cube_one_camera  # commanded: the cameras judge


def test_one_camera_places_the_cube_only_where_the_gripper_can_feel(
    spec: ArmSpec, sight: RigSight
) -> None:
    both = _pair(sight, blank_right=False)
    for build in (spec, PWM):  # both cameras: either build places it, within millimetres
        seen = _cube(sight, build, both)
        assert seen is not None and np.linalg.norm(seen - CUBE_M) < 0.005
    # the right camera sees nothing: the measured build still places the cube from the left
    # view alone (here 3 cm off, under the table: depth from the printed marker size); the bare
    # build, whose grasp the cameras judge, does not take that as a sighting
    one = _pair(sight, blank_right=True)
    assert _cube(sight, spec, one) is not None
    assert _cube(sight, PWM, one) is None


class _StillPair:
    """A frame source that serves one captured pair, as a camera that saw it at ``capture_s``."""

    timeout_s = 1e9

    def __init__(self, pair: FramePair) -> None:
        self.pair = pair

    def start(self) -> None:
        """Nothing to start."""

    def latest(self) -> FramePair:
        return self.pair

    def close(self) -> None:
        """Nothing to release."""


def test_the_cube_comes_with_the_tool_where_it_was_when_the_cube_was_seen(
    sight: RigSight,
) -> None:
    """Cameras see the cube late and the tool comes from this period's readings: the percept
    pairs the cube with forward kinematics of the readings at the capture time of the cube's
    frame, which is what a grasp judged from the cameras compares (``pick.held_seen``). Once
    the cube is hidden its estimate is the last sighting, paired with the tool of the newest
    frame, as the env's delay line pairs them."""
    pair = _pair(sight, blank_right=False)
    capture_s = pair.capture_s
    source = _StillPair(pair)
    perception = StereoPerception(source, sight.stereo, sight.base_T_left, PWM, ("cube",),
                                  sight.layout, worker="thread")  # fmt: skip
    q_then = np.array(PWM.actuator_park_rad, dtype=float)
    q_mid = q_then + np.array([0.15, -0.1, 0.12, 0.0])
    q_now = q_then + np.array([0.3, -0.2, 0.25, 0.0])  # moved on since the capture
    n = PWM.n_joints

    def wait_for(q: np.ndarray, t_s: float, done: Callable[[Percept], bool]) -> None:
        deadline = time.monotonic() + scaled(60.0)  # the worker measures in its own time
        while not done(perception.perceive(ArmState(q, 0.0), t_s)):
            assert time.monotonic() < deadline, "the worker never measured the pair"
            time.sleep(0.01)

    perception.start()
    try:
        wait_for(q_then, capture_s, lambda p: "cube" in p.objects)
        later = perception.perceive(ArmState(q_now, 0.0), capture_s + 0.15)
        # the cube hidden from both cameras in the next pair
        blank = np.zeros_like(pair.left_bgr)
        source.pair = FramePair(blank, blank, capture_s + 0.3, 2)
        wait_for(q_mid, capture_s + 0.3, lambda p: p.blind_s("cube") > 0.0)
        hidden = perception.perceive(ArmState(q_now, 0.0), capture_s + 0.45)
    finally:
        perception.close()
    cube = later.objects["cube"]
    assert cube.blind_s == 0.0 and np.linalg.norm(cube.position_m - CUBE_M) < 0.005
    assert later.tool_m is not None and cube.tool_then_m is not None
    moved = PWM.forward_kinematics(q_now[:n]) - PWM.forward_kinematics(q_then[:n])
    assert np.linalg.norm(moved) > 0.03
    np.testing.assert_allclose(later.tool_m - cube.tool_then_m, moved, atol=1e-9)
    np.testing.assert_allclose(later.tool_then("cube"), cube.tool_then_m)
    # hidden: the last sighting, with the tool of the newest frame (not of the last sighting)
    still = hidden.objects["cube"]
    assert still.blind_s > 0.0 and np.allclose(still.position_m, cube.position_m)
    assert hidden.tool_m is not None and still.tool_then_m is not None
    np.testing.assert_allclose(
        hidden.tool_m - still.tool_then_m,
        PWM.forward_kinematics(q_now[:n]) - PWM.forward_kinematics(q_mid[:n]),
        atol=1e-9,
    )
