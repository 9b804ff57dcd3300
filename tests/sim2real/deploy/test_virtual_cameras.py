"""Rendered stereo frames through real OpenCV: markers found, triangulated to the truth."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.markers import ArucoMarkerDetector
from hardware.spec import ArmSpec
from sim2real import model as names
from sim2real.deploy.virtual_cameras import VirtualStereoCameras, marker_image, stereo_rig_of
from sim2real.envs.workspace import sample_reachable


@pytest.fixture(scope="module")
def cams(spec: ArmSpec) -> VirtualStereoCameras:
    c = VirtualStereoCameras(spec)
    yield c
    c.close()


def test_marker_texture_is_a_decodable_aruco_marker() -> None:
    img = marker_image(names.TARGET_MARKER_ID)
    found = ArucoMarkerDetector(names.MARKER_DICTIONARY).detect(np.dstack([img] * 3))
    assert [m.id for m in found] == [names.TARGET_MARKER_ID]


def test_rendered_markers_triangulate_to_their_true_positions(
    spec: ArmSpec, cams: VirtualStereoCameras
) -> None:
    rig, base_T_left = stereo_rig_of(cams.rig)
    det = ArucoMarkerDetector(names.MARKER_DICTIONARY)
    rng = np.random.default_rng(0)
    errors = []
    for _ in range(8):
        target = sample_reachable(spec, rng)
        cams.pose(spec.actuator_park_rad, target)  # parked: nothing hides the target
        frames = cams.read()
        assert frames.left_bgr.shape == (480, 640, 3)
        left = {m.id: m for m in det.detect(frames.left_bgr)}
        right = {m.id: m for m in det.detect(frames.right_bgr)}
        assert names.TARGET_MARKER_ID in left and names.TARGET_MARKER_ID in right
        m_l, m_r = left[names.TARGET_MARKER_ID], right[names.TARGET_MARKER_ID]
        corners = rig.triangulate(m_l.corners_px, m_r.corners_px)
        centre = (corners @ base_T_left[:3, :3].T + base_T_left[:3, 3]).mean(axis=0)
        errors.append(np.linalg.norm(centre - target))
        # The four corners are a square of the marker's size: the geometry is metric.
        side = np.linalg.norm(np.diff(np.vstack([corners, corners[:1]]), axis=0), axis=1)
        np.testing.assert_allclose(side, names.TARGET_MARKER_SIZE_M, rtol=0.08)
    assert np.median(errors) < 0.002 and max(errors) < 0.004


def test_stereo_rig_of_matches_the_rendered_geometry(cams: VirtualStereoCameras) -> None:
    rig, _ = stereo_rig_of(cams.rig)
    assert rig.baseline == pytest.approx(cams.rig.baseline_m)
    assert rig.left.image_size == (640, 480)
