"""The marker cube and the seam plates through MuJoCo rendering and real OpenCV: the cube is found
within millimetres, coasts while hidden with a growing ``blind_s``, is re-acquired where it
reappears, and a cube never seen is reported, not crashed on."""

from __future__ import annotations

import math
from collections.abc import Iterator

import mujoco
import numpy as np
import pytest

from calibration.cube import MarkerCube, wrap_yaw
from calibration.cube_tracker import StereoCubeTracker, StereoSeamTracker
from calibration.errors import CalibrationError, ConfigError
from calibration.markers import ArucoMarkerDetector
from hardware.spec import ArmSpec
from sim2real import model as names
from sim2real.deploy.marker_textures import marker_image
from sim2real.deploy.virtual_cameras import VirtualStereoCameras, stereo_rig_of

PERIOD_S = 0.05  # the deploy loop's 20 Hz


@pytest.fixture(scope="module")
def pick_cams(spec: ArmSpec) -> Iterator[VirtualStereoCameras]:
    cams = VirtualStereoCameras(spec, scene="pick")
    yield cams
    cams.close()


def _place_cube(cams: VirtualStereoCameras, spec: ArmSpec, p_m: np.ndarray, yaw_rad: float) -> None:
    a = int(cams.model.joint(names.CUBE_JOINT).qposadr[0])
    cams.data.qpos[a : a + 3] = p_m
    cams.data.qpos[a + 3 : a + 7] = (math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2))
    cams.pose(spec.actuator_park_rad, None)


def _tracker(cams: VirtualStereoCameras) -> StereoCubeTracker:
    rig, base_T_left = stereo_rig_of(cams.rig)
    return StereoCubeTracker(rig, base_T_left, names.MARKER_CUBE)


def test_cube_face_textures_decode_to_their_ids() -> None:
    det = ArucoMarkerDetector(names.MARKER_DICTIONARY)
    for marker_id in names.MARKER_CUBE.face_ids:
        img = marker_image(marker_id, names.CUBE_MARKER_TEXTURE_PX)
        found = det.detect(np.dstack([img] * 3))
        assert [m.id for m in found] == [marker_id]
        side = found[0].side_px
        expected = names.CUBE_MARKER_TEXTURE_PX * names.MARKER_CUBE.marker_fill
        assert side == pytest.approx(expected, abs=2.0)


def test_rendered_cube_is_found_within_millimetres(
    spec: ArmSpec, pick_cams: VirtualStereoCameras
) -> None:
    tracker = _tracker(pick_cams)
    rng = np.random.default_rng(3)
    errors, yaw_errors = [], []
    for _ in range(6):
        r, a = rng.uniform(0.12, 0.19), rng.uniform(-0.5, 0.5)
        p = np.array([r * math.cos(a), r * math.sin(a), names.MARKER_CUBE.half_m])
        yaw = rng.uniform(-math.pi / 4, math.pi / 4)
        _place_cube(pick_cams, spec, p, yaw)
        frames = pick_cams.read()
        fit = tracker.measure(frames.left_bgr, frames.right_bgr)
        if fit is None:  # a yaw near 45° can leave no face seen by both cameras: rare, allowed
            continue
        assert set(fit.face_ids) <= set(names.MARKER_CUBE.face_ids)
        errors.append(float(np.linalg.norm(fit.position_m - p)))
        yaw_errors.append(abs(wrap_yaw(fit.yaw_rad - yaw)))
    assert len(errors) >= 5
    assert max(errors) < 0.004 and math.sqrt(np.mean(np.square(errors))) < 0.003
    assert math.degrees(max(yaw_errors)) < 6.0


def test_hidden_cube_coasts_reports_blind_time_and_is_reacquired(
    spec: ArmSpec, pick_cams: VirtualStereoCameras
) -> None:
    tracker = _tracker(pick_cams)
    rest = np.array([0.16, 0.02, names.MARKER_CUBE.half_m])
    _place_cube(pick_cams, spec, rest, 0.2)
    seen = pick_cams.read()
    t = 0.0
    for _ in range(3):
        est = tracker.observe(seen.left_bgr, seen.right_bgr, t)
        assert est.valid and est.blind_s == 0.0 and est.faces_seen
        t += PERIOD_S
    last_seen_s = t - PERIOD_S
    settled = est.position_m.copy()
    assert np.linalg.norm(settled - rest) < 0.003

    # Hidden: the cube is under the table, as it is inside the fingers during a grasp.
    _place_cube(pick_cams, spec, np.array([0.16, 0.02, -0.1]), 0.2)
    hidden = pick_cams.read()
    for _ in range(int(1.0 / PERIOD_S)):
        est = tracker.observe(hidden.left_bgr, hidden.right_bgr, t)
        assert est.valid and est.faces_seen == () and est.coasting
        assert est.blind_s == pytest.approx(t - last_seen_s)
        assert np.linalg.norm(est.position_m - settled) < 0.001  # coasts where it was
        ahead = tracker.predict(t + 0.08)
        assert ahead.valid and ahead.blind_s == pytest.approx(t + 0.08 - last_seen_s)
        t += PERIOD_S
    assert est.blind_s >= 0.95

    # Reappears 4 cm higher (carried while hidden): one frame re-acquires it, not the gate.
    lifted = rest + np.array([0.0, 0.0, 0.04])
    _place_cube(pick_cams, spec, lifted, 0.2)
    back = pick_cams.read()
    est = tracker.observe(back.left_bgr, back.right_bgr, t)
    assert est.valid and est.blind_s == 0.0 and est.faces_seen
    assert np.linalg.norm(est.position_m - lifted) < 0.004
    # The same pair handed over again (no new camera frame) is not counted twice.
    assert tracker.observe(back.left_bgr, back.right_bgr, t) is est


def test_a_lost_cube_is_searched_whole_only_every_nth_pair(
    spec: ArmSpec, pick_cams: VirtualStereoCameras
) -> None:
    """Upscaled full frames are the tracker's dearest step: while blind after a sighting, the
    other pairs only look around where the cube was."""
    tracker = _tracker(pick_cams)
    _place_cube(pick_cams, spec, np.array([0.16, 0.02, names.MARKER_CUBE.half_m]), 0.2)
    seen = pick_cams.read()
    _place_cube(pick_cams, spec, np.array([0.16, 0.02, -0.1]), 0.2)
    hidden = pick_cams.read()
    full_searches: list[int] = []
    detect = tracker.detector.detect

    def counting(image: np.ndarray, roi: tuple[int, int, int, int] | None = None) -> list:
        if roi is None:
            full_searches[-1] += 1
        return detect(image, roi)

    tracker.detector.detect = counting  # type: ignore[method-assign]
    for k, frames in enumerate([seen] * 2 + [hidden] * 9):
        full_searches.append(0)
        tracker.observe(frames.left_bgr, frames.right_bgr, k * PERIOD_S)
    assert full_searches[:2] == [2, 0]  # acquired whole, then tracked in its region
    assert full_searches[2:] == [2, 0, 0, 0, 2, 0, 0, 0, 2]  # every 4th blind pair, both images


def test_a_cube_never_seen_is_reported_not_crashed_on(
    spec: ArmSpec, pick_cams: VirtualStereoCameras
) -> None:
    tracker = _tracker(pick_cams)
    _place_cube(pick_cams, spec, np.array([0.16, 0.0, -0.1]), 0.0)  # out of sight
    frames = pick_cams.read()
    assert tracker.predict(0.0).valid is False
    for k in range(5):
        est = tracker.observe(frames.left_bgr, frames.right_bgr, k * PERIOD_S)
        assert not est.valid and math.isinf(est.blind_s) and est.faces_seen == ()
        assert np.all(np.isnan(est.position_m)) and math.isnan(est.yaw_rad)
    assert "never seen" in est.reason and "[2, 3, 4, 5, 6]" in est.reason
    assert "\n" not in est.reason and "5 frame pair" in est.reason
    assert not tracker.predict(1.0).valid

    small = frames.left_bgr[::2, ::2]
    with pytest.raises(CalibrationError, match="320x240 frames but the stereo calibration"):
        _tracker(pick_cams).observe(small, small, 0.0)
    with pytest.raises(ConfigError, match="uint8 image"):
        _tracker(pick_cams).observe(frames.left_bgr.astype(float), frames.right_bgr, 0.0)


def test_cube_markers_leave_the_cube_physics_unchanged(spec: ArmSpec) -> None:
    plain = names.build_model(spec, "pick", markers=False)
    marked = names.build_model(spec, "pick", markers=True)
    for scene in names.SCENES:  # the training scenes carry no marker at all
        assert "aruco_" not in names.build_mjcf(spec, scene)
    assert MarkerCube() == names.MARKER_CUBE  # the sheet's and the tracker's defaults
    for m in (plain, marked):
        assert m.body(names.CUBE_BODY).mass[0] == pytest.approx(0.03)
    np.testing.assert_allclose(
        marked.body(names.CUBE_BODY).inertia, plain.body(names.CUBE_BODY).inertia
    )
    trajectories = []
    for m in (plain, marked):
        d = mujoco.MjData(m)
        a = int(m.joint(names.CUBE_JOINT).qposadr[0])
        d.qpos[a : a + 7] = (0.15, 0.03, 0.05, math.cos(0.2), 0.1, 0.0, math.sin(0.2))
        mujoco.mj_forward(m, d)
        for _ in range(100):  # falls, tumbles and lands on the table
            mujoco.mj_step(m, d)
        trajectories.append(d.qpos[a : a + 7].copy())
    np.testing.assert_allclose(trajectories[0], trajectories[1], atol=1e-12)


def test_seam_ends_from_the_rendered_end_plates(spec: ArmSpec) -> None:
    cams = VirtualStereoCameras(spec, scene="trace")
    try:
        rig, base_T_left = stereo_rig_of(cams.rig)
        tracker = StereoSeamTracker(rig, base_T_left, names.SEAM_MARKERS)
        seam = cams.model.body_mocapid[cams.model.body(names.SEAM_BODY).id]
        heading = 0.6
        start = np.array([0.12, -0.06, names.SEAM_BODY_Z_M])
        cams.data.mocap_pos[seam] = start
        cams.data.mocap_quat[seam] = (math.cos(heading / 2), 0.0, 0.0, math.sin(heading / 2))
        cams.pose(spec.actuator_park_rad, None)
        frames = cams.read()
        est = tracker.observe(frames.left_bgr, frames.right_bgr, 0.0)
        assert est.valid and est.blind_s == 0.0
        end = start + names.SEAM_LENGTH_M * np.array([math.cos(heading), math.sin(heading), 0.0])
        assert np.linalg.norm(est.start_m[:2] - start[:2]) < 0.004
        assert np.linalg.norm(est.end_m[:2] - end[:2]) < 0.004
        assert abs(est.start_m[2]) < 0.004  # the plates lie on the table
        assert tracker.observe(frames.left_bgr, frames.right_bgr, 0.0) is est  # not re-counted
        later = tracker.predict(0.5)
        assert later.valid and later.blind_s == pytest.approx(0.5)
    finally:
        cams.close()
