"""ArUco detection with sub-pixel corners and the colour-blob alternative, on rendered images."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calibration.camera import CameraModel
from calibration.errors import ConfigError, UnknownNameError
from calibration.markers import ArucoMarkerDetector, ColorBlobDetector, marker_corners
from calibration.synthetic import facing_camera, pose, render_marker
from calibration.triangulate import StereoRig

CAM = CameraModel.from_fovy(45.0, 640, 480)


def _truth(cam: CameraModel, cam_T_marker: np.ndarray, length: float) -> np.ndarray:
    return cam.project(marker_corners(length) @ cam_T_marker[:3, :3].T + cam_T_marker[:3, 3])


@pytest.mark.parametrize("roll_deg", [0.0, 70.0, 180.0, -120.0])
def test_aruco_corners_subpixel_and_in_marker_order(roll_deg: float) -> None:
    cam_T_marker = pose(facing_camera(15, -20, roll_deg), [0.04, -0.03, 0.5])
    img = render_marker(
        CAM, cam_T_marker, np.random.default_rng(0), marker_id=7, marker_length_m=0.04
    )
    marker = ArucoMarkerDetector("DICT_4X4_50").find(img, 7)
    assert marker is not None
    err = np.linalg.norm(marker.corners_px - _truth(CAM, cam_T_marker, 0.04), axis=1)
    assert err.max() < 0.5, err  # corner order follows the marker, not the image
    # sub-pixel refinement matters: the centre is far better than the 0.5 px pixel grid
    truth_centre = _truth(CAM, cam_T_marker, 0.04).mean(axis=0)
    assert np.linalg.norm(marker.centre_px - truth_centre) < 0.1


def test_roi_search_returns_full_image_coordinates() -> None:
    cam_T_marker = pose(facing_camera(0, 10, 0), [-0.05, 0.04, 0.45])
    img = render_marker(CAM, cam_T_marker, np.random.default_rng(1), marker_id=2)
    det = ArucoMarkerDetector()
    full = det.find(img, 2)
    assert full is not None
    in_roi = det.find(img, 2, full.roi(1.0))
    assert in_roi is not None
    np.testing.assert_allclose(in_roi.corners_px, full.corners_px, atol=0.05)
    assert det.find(img, 2, (0, 0, 60, 60)) is None  # nothing in a far corner
    assert det.find(img, 3) is None  # another id
    bgr = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    assert det.find(bgr, 2) is not None


def test_unknown_dictionary() -> None:
    with pytest.raises(UnknownNameError, match="DICT_4X4_50"):
        ArucoMarkerDetector("DICT_3X3_7")


def _disc_image(
    centre: tuple[float, float], radius: float, bgr: tuple[int, int, int]
) -> np.ndarray:
    """A 4× supersampled anti-aliased disc, so its centroid is sub-pixel exact."""
    big = np.full((480 * 4, 640 * 4, 3), (40, 40, 40), np.uint8)
    cx, cy = ((c + 0.5) * 4 - 0.5 for c in centre)
    cv2.circle(
        big,
        (round(cx * 16), round(cy * 16)),
        round(radius * 4 * 16),
        bgr,
        -1,
        lineType=cv2.LINE_AA,
        shift=4,
    )
    return cv2.resize(big, (640, 480), interpolation=cv2.INTER_AREA)


def test_colour_blob_centroid() -> None:
    img = _disc_image((250.3, 310.7), 12.0, (30, 30, 220))  # red in BGR
    red = ColorBlobDetector((170, 120, 80), (10, 255, 255))  # hue wraps around 0
    blob = red.detect(img)
    assert blob is not None
    np.testing.assert_allclose(blob.centre_px, [250.3, 310.7], atol=0.1)
    assert blob.area_px == pytest.approx(np.pi * 144, rel=0.1)
    assert red.detect(img, blob.roi(1.0)) is not None
    assert ColorBlobDetector((50, 120, 80), (70, 255, 255)).detect(img) is None  # no green


def test_colour_blob_triangulates(rig: StereoRig) -> None:
    """A small ball seen by both cameras: centroids → triangulated centre within ~2 mm."""
    left_p = np.array([0.03, -0.02, 0.5])
    uv_l = rig.left.project(left_p[None])[0]
    uv_r = rig.right.project((rig.R @ left_p + rig.T)[None])[0]
    radius_px = 6.0
    det = ColorBlobDetector((100, 120, 80), (130, 255, 255))  # blue
    blobs = [det.detect(_disc_image(tuple(uv), radius_px, (220, 60, 30))) for uv in (uv_l, uv_r)]
    assert all(b is not None for b in blobs)
    p = rig.triangulate(blobs[0].centre_px, blobs[1].centre_px)[0]  # type: ignore[union-attr]
    assert np.linalg.norm(p - left_p) < 0.002


def test_colour_range_validation() -> None:
    with pytest.raises(ConfigError, match="low_hsv"):
        ColorBlobDetector((200, 0, 0), (10, 255, 255))
    with pytest.raises(ConfigError, match="BGR image"):
        ColorBlobDetector((0, 0, 0), (10, 255, 255)).detect(np.zeros((4, 4), np.uint8))
