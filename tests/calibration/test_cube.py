"""The marker cube's geometry and the cube tracker's measurement, against exact projections.

Face corners are projected through the distorted example rig with pixel noise, so undistortion,
triangulation, per-face fusion and the two-image refinement are all exercised against truth.
Rendered (MuJoCo) frames are in ``tests/sim2real/deploy/test_marker_cube.py``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from calibration.cube import (
    FACE_NAMES,
    FaceObservation,
    MarkerCube,
    SeamMarkers,
    centre_and_yaw,
    face_net_layout,
    mean_yaw,
    wrap_yaw,
)
from calibration.cube_tracker import (
    StereoCubeTracker,
    corner_models,
    residual_and_jacobian,
    yaw_of,
)
from calibration.errors import ConfigError
from calibration.markers import Marker
from calibration.synthetic import example_rig, pose, rotation
from calibration.triangulate import StereoRig

CUBE = MarkerCube()
# The left camera 0.5 m from the cube, looking down at it at 45° (like the deploy rig).
BASE_T_LEFT = pose(rotation(-135.0, 0.0, 90.0), [0.5, 0.0, 0.36])


def _base_T_cube(p_m: np.ndarray, yaw_rad: float, tumble_deg: float = 0.0) -> np.ndarray:
    return pose(rotation(0.0, 0.0, math.degrees(yaw_rad)) @ rotation(tumble_deg, 0.0, 0.0), p_m)


def _markers(
    rig: StereoRig,
    base_T_cube: np.ndarray,
    rng: np.random.Generator,
    noise_px: float = 0.2,
    roll: dict[int, int] | None = None,
) -> tuple[list[Marker], list[Marker]]:
    """Project every face that a camera sees at less than 70° from its normal."""
    out: tuple[list[Marker], list[Marker]] = ([], [])
    left_T_base = np.linalg.inv(BASE_T_LEFT)
    for side, cam_T_left in enumerate((np.eye(4), rig.right_T_left)):
        cam = rig.left if side == 0 else rig.right
        cam_T_cube = cam_T_left @ left_T_base @ base_T_cube
        for marker_id in CUBE.face_ids:
            T = cam_T_cube @ CUBE.cube_T_face(marker_id)
            to_cam = -T[:3, 3] / np.linalg.norm(T[:3, 3])
            if float(T[:3, 2] @ to_cam) < math.cos(math.radians(70)):
                continue
            corners = CUBE.face_corners_m(marker_id) @ cam_T_cube[:3, :3].T + cam_T_cube[:3, 3]
            uv = cam.project(corners) + rng.normal(0.0, noise_px, (4, 2))
            uv = np.roll(uv, (roll or {}).get(marker_id, 0), axis=0)
            out[side].append(Marker(marker_id, uv))
    return out


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"marker_m": 0.025}, "white margin"),
        ({"size_m": -0.02}, "size_m"),
        ({"face_ids": (2, 3, 4, 5)}, "needs 5 ids"),
        ({"face_ids": (2, 3, 4, 5, 5)}, "distinct"),
        ({"face_ids": (2, 3, 4, 5, 50)}, "marker id 50 is not an id of DICT_4X4_50"),
    ],
)
def test_cube_config_errors_name_the_value(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        MarkerCube(**kwargs)  # type: ignore[arg-type]


def test_face_frames_are_outward_right_handed_and_on_the_faces() -> None:
    for marker_id in CUBE.face_ids:
        T = CUBE.cube_T_face(marker_id)
        R = T[:3, :3]
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(T[:3, 3], CUBE.half_m * R[:, 2])  # centre on the face
        corners = CUBE.face_corners_m(marker_id)
        np.testing.assert_allclose(corners @ R[:, 2], CUBE.half_m)
        side = np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1)
        np.testing.assert_allclose(side, CUBE.marker_m)
        if CUBE.face_name(marker_id) != "+z":
            assert R[:, 1] == pytest.approx([0.0, 0.0, 1.0])  # side markers stand upright
    with pytest.raises(ConfigError, match="not on the cube"):
        CUBE.face_name(0)


def test_net_turns_point_each_side_marker_up_at_the_top_face() -> None:
    layout = face_net_layout(CUBE)
    assert sorted(layout) == sorted(CUBE.face_ids)
    centre = np.array(layout[CUBE.face_ids[0]][0])
    for marker_id, (cell, turns) in layout.items():
        if CUBE.face_name(marker_id) == "+z":
            assert turns == 0 and cell == (1, 1)
            continue
        # Sheet coordinates: x right, y up (rows grow downwards).
        towards_centre = np.array([centre[0] - cell[0], -(centre[1] - cell[1])])
        c, s = round(math.cos(turns * math.pi / 2)), round(math.sin(turns * math.pi / 2))
        up = np.array([[c, -s], [s, c]]) @ np.array([0, 1])
        assert up.tolist() == towards_centre.tolist(), CUBE.face_name(marker_id)
        # Folding keeps the face's own axes: the net cell lies in the face normal's direction.
        normal_xy = np.array(
            {"+x": (1, 0), "-x": (-1, 0), "+y": (0, 1), "-y": (0, -1)}[CUBE.face_name(marker_id)]
        )
        assert (-towards_centre).tolist() == normal_xy.tolist()


def test_yaw_is_modulo_the_cube_symmetry() -> None:
    assert wrap_yaw(math.radians(50)) == pytest.approx(math.radians(-40))
    assert wrap_yaw(math.radians(-45)) == pytest.approx(math.radians(-45))
    assert abs(mean_yaw(np.radians([44.0, -44.0]))) == pytest.approx(math.radians(45))
    assert mean_yaw(np.radians([10.0, 100.0, -80.0])) == pytest.approx(math.radians(10))


def test_each_face_gives_centre_and_yaw_whatever_way_its_marker_is_glued() -> None:
    p = np.array([0.17, -0.03, CUBE.half_m])
    base_T_cube = _base_T_cube(p, math.radians(20))
    for marker_id in CUBE.face_ids:
        for quarter_turns in range(4):
            turn = pose(rotation(0.0, 0.0, 90.0 * quarter_turns), np.zeros(3))
            face = FaceObservation(marker_id, base_T_cube @ CUBE.cube_T_face(marker_id) @ turn, 0.0)
            centre, yaw = centre_and_yaw(CUBE, face)
            np.testing.assert_allclose(centre, p, atol=1e-12)
            assert yaw == pytest.approx(math.radians(20))


@pytest.mark.parametrize(
    ("yaw_deg", "tumble_deg"), [(0.0, 0.0), (30.0, 0.0), (-40.0, 0.0), (15.0, 90.0)]
)
def test_measured_cube_matches_truth_through_a_distorted_rig(
    yaw_deg: float, tumble_deg: float
) -> None:
    rig = example_rig()
    tracker = StereoCubeTracker(rig, BASE_T_LEFT, CUBE)
    rng = np.random.default_rng(int(yaw_deg + tumble_deg) + 100)
    errors, yaw_errors = [], []
    for _ in range(10):
        p = np.array([rng.uniform(0.12, 0.2), rng.uniform(-0.05, 0.05), CUBE.half_m])
        yaw = math.radians(yaw_deg)
        left, right = _markers(rig, _base_T_cube(p, yaw, tumble_deg), rng)
        fit = tracker.measure_markers(left, right)
        assert fit is not None and fit.reprojection_px is not None
        assert fit.reprojection_px < 0.5
        assert set(fit.face_ids) == {m.id for m in left + right}
        errors.append(np.linalg.norm(fit.position_m - p))
        yaw_errors.append(abs(wrap_yaw(fit.yaw_rad - yaw)))
    assert max(errors) < 0.0015
    assert math.degrees(max(yaw_errors)) < 1.5


def test_refinement_jacobian_matches_finite_differences() -> None:
    rig = example_rig()
    rng = np.random.default_rng(5)
    base_T_cube = _base_T_cube(np.array([0.16, 0.02, CUBE.half_m]), 0.4)
    markers = _markers(rig, base_T_cube, rng)
    assert markers[0] and markers[1]
    models = corner_models(CUBE, markers)
    left_T_cube = np.linalg.inv(BASE_T_LEFT) @ base_T_cube
    rvec = cv2.Rodrigues(left_T_cube[:3, :3])[0].ravel()
    params = np.concatenate([rvec + 0.01, left_T_cube[:3, 3] + 0.002, [0.97]])
    _, J = residual_and_jacobian(rig, models, params)
    numeric = np.empty_like(J)
    for k in range(7):
        step = np.zeros(7)
        step[k] = 1e-6
        numeric[:, k] = (
            residual_and_jacobian(rig, models, params + step)[0]
            - residual_and_jacobian(rig, models, params - step)[0]
        ) / 2e-6
    np.testing.assert_allclose(J, numeric, rtol=1e-4, atol=1e-3)  # px per unit; |J| ~ 1e3


def test_refinement_beats_per_face_triangulation() -> None:
    """The two-image rigid fit is the point of the refinement: compare it with the per-face
    stereo fusion on the same noisy corners."""
    rig = example_rig()
    refined = StereoCubeTracker(rig, BASE_T_LEFT, CUBE)
    stereo = StereoCubeTracker(rig, BASE_T_LEFT, CUBE, refine=False, max_spread_m=1.0)
    rng = np.random.default_rng(7)
    err_refined, err_stereo = [], []
    for _ in range(30):
        p = np.array([rng.uniform(0.12, 0.2), rng.uniform(-0.05, 0.05), CUBE.half_m])
        left, right = _markers(rig, _base_T_cube(p, rng.uniform(-0.7, 0.7)), rng, noise_px=0.4)
        a, b = refined.measure_markers(left, right), stereo.measure_markers(left, right)
        assert a is not None and b is not None and b.reprojection_px is None
        err_refined.append(np.linalg.norm(a.position_m - p))
        err_stereo.append(np.linalg.norm(b.position_m - p))
    assert np.sqrt(np.mean(np.square(err_refined))) < 0.75 * np.sqrt(np.mean(np.square(err_stereo)))


def test_a_marker_glued_turned_falls_back_to_the_per_face_estimate() -> None:
    """A face whose marker does not match the net's orientation cannot fit the rigid model;
    the per-face estimate (which ignores in-plane orientation) still places the cube."""
    rig = example_rig()
    tracker = StereoCubeTracker(rig, BASE_T_LEFT, CUBE)
    rng = np.random.default_rng(11)
    p = np.array([0.16, 0.01, CUBE.half_m])
    left, right = _markers(rig, _base_T_cube(p, 0.3), rng, noise_px=0.1, roll={3: 1})
    assert {m.id for m in left} >= {2, 3}
    fit = tracker.measure_markers(left, right)
    assert fit is not None and fit.reprojection_px is None  # the refinement was refused
    assert np.linalg.norm(fit.position_m - p) < 0.004


def test_yaw_of_a_cube_lying_on_any_face() -> None:
    for tumble in (0.0, 90.0, 180.0, -90.0):
        R = _base_T_cube(np.zeros(3), math.radians(25), tumble)[:3, :3]
        assert yaw_of(R) == pytest.approx(math.radians(25))


def test_blank_frames_are_a_cube_never_seen() -> None:
    rig = example_rig()
    tracker = StereoCubeTracker(rig, BASE_T_LEFT, CUBE)
    blank = np.full((480, 640, 3), 200, np.uint8)
    est = tracker.observe(blank, blank, 0.0)
    assert not est.valid and math.isinf(est.blind_s) and "never seen" in est.reason
    with pytest.raises(ConfigError, match="timestamps must not go backwards"):
        tracker.observe(blank, blank, -1.0)


def test_seam_ends_from_plate_centres() -> None:
    seam = SeamMarkers(end_offset_m=0.02)
    start, end = seam.seam_ends(np.array([0.0, 0.0, 0.0]), np.array([0.2, 0.0, 0.0]))
    np.testing.assert_allclose(start, [0.02, 0.0, 0.0])
    np.testing.assert_allclose(end, [0.18, 0.0, 0.0])
    with pytest.raises(ConfigError, match="apart"):
        seam.seam_ends(np.zeros(3), np.array([0.03, 0.0, 0.0]))
    with pytest.raises(ConfigError, match="distinct"):
        SeamMarkers(start_id=7, end_id=7)


def test_face_names_cover_the_five_visible_faces() -> None:
    assert FACE_NAMES == ("+z", "+x", "-x", "+y", "-y")


@pytest.mark.parametrize("side", [0, 1])
def test_a_cube_seen_by_one_camera_only_is_placed_from_that_camera(side: int) -> None:
    """The arm descending on the cube often hides it from one camera: the faces the other
    still sees place it (printed size imposed), within millimetres at half a metre."""
    rig = example_rig()
    tracker = StereoCubeTracker(rig, BASE_T_LEFT, CUBE)
    rng = np.random.default_rng(21 + side)
    errors = []
    for _ in range(10):
        p = np.array([rng.uniform(0.12, 0.2), rng.uniform(-0.05, 0.05), CUBE.half_m])
        yaw = rng.uniform(-0.7, 0.7)
        markers = _markers(rig, _base_T_cube(p, yaw), rng, noise_px=0.2)
        one = (markers[0], []) if side == 0 else ([], markers[1])
        assert one[side]
        fit = tracker.measure_markers(*one)
        assert fit is not None and fit.reprojection_px is not None
        assert fit.reprojection_px < 0.5
        assert set(fit.face_ids) == {m.id for m in one[side]}
        assert abs(wrap_yaw(fit.yaw_rad - yaw)) < math.radians(3.0)
        errors.append(np.linalg.norm(fit.position_m - p))
    assert max(errors) < 0.006  # depth from the printed size: coarser than stereo's 1.5 mm
    off = StereoCubeTracker(rig, BASE_T_LEFT, CUBE, single_view=False)
    assert off.measure_markers(*one) is None


def test_different_faces_in_the_two_cameras_still_triangulate_through_the_rigid_fit() -> None:
    """No face in both images, but a face in each: the rigid cube fitted to both images has
    disparity again, so it is as good as stereo."""
    rig = example_rig()
    tracker = StereoCubeTracker(rig, BASE_T_LEFT, CUBE)
    rng = np.random.default_rng(31)
    checked = 0
    for _ in range(40):
        p = np.array([rng.uniform(0.12, 0.2), rng.uniform(-0.05, 0.05), CUBE.half_m])
        left, right = _markers(rig, _base_T_cube(p, rng.uniform(-0.7, 0.7)), rng, noise_px=0.2)
        right_ids = {m.id for m in right}
        left_only = [m for m in left if m.id not in right_ids]
        if not left_only or len(right) < 1:
            continue
        # hide every face the left camera shares with the right one
        right_kept = [m for m in right if m.id not in {x.id for x in left_only}]
        if not right_kept:
            continue
        fit = tracker.measure_markers(left_only, right_kept)
        assert fit is not None and fit.reprojection_px is not None
        assert np.linalg.norm(fit.position_m - p) < 0.003
        checked += 1
    assert checked >= 5


def test_a_single_view_fit_that_does_not_reproject_is_a_miss() -> None:
    """Corners that no rigid cube explains (a false detection) are refused, not reported."""
    rig = example_rig()
    tracker = StereoCubeTracker(rig, BASE_T_LEFT, CUBE)
    rng = np.random.default_rng(41)
    p = np.array([0.16, 0.0, CUBE.half_m])
    left, _ = _markers(rig, _base_T_cube(p, 0.2), rng, noise_px=0.1)
    assert len(left) >= 2
    # two faces from two different cubes 5 cm apart: no single rigid cube fits both
    other, _ = _markers(rig, _base_T_cube(p + (0.0, 0.05, 0.0), 0.2), rng, noise_px=0.1)
    mixed = [left[0]] + [m for m in other if m.id != left[0].id][:1]
    assert tracker.measure_markers(mixed, []) is None
