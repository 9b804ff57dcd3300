"""Synthetic ground truth for tests and benches: boards and markers seen by a known camera.

Planar textures (a board from :mod:`calibration.boards`, an ArUco marker) are rendered into a
camera with known K, distortion and pose by inverse mapping: every output pixel (supersampled,
then area-averaged) is undistorted to a ray, intersected with the plane and looked up in the
texture with ``cv2.remap``. Distortion is therefore rendered exactly, which ``warpPerspective``
cannot do. Points can also be projected directly with ``cv2.projectPoints`` plus Gaussian noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, cast

import cv2
import numpy as np
from numpy.typing import ArrayLike

from calibration.boards import BoardSpec, Detection, aruco_dictionary
from calibration.camera import CameraModel
from calibration.triangulate import StereoRig

_RAY_CACHE: dict[tuple[bytes, bytes, tuple[int, int], int], tuple[np.ndarray, np.ndarray]] = {}


def pose(R: ArrayLike, t: ArrayLike) -> np.ndarray:
    """A 4×4 homogeneous transform ``a_T_b`` from a rotation (3×3) and translation (3,)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.ravel(t)
    return T


def rotation(rx_deg: float = 0.0, ry_deg: float = 0.0, rz_deg: float = 0.0) -> np.ndarray:
    """R = Rz·Ry·Rx from angles in degrees (x first)."""
    cx, sx = math.cos(math.radians(rx_deg)), math.sin(math.radians(rx_deg))
    cy, sy = math.cos(math.radians(ry_deg)), math.sin(math.radians(ry_deg))
    cz, sz = math.cos(math.radians(rz_deg)), math.sin(math.radians(rz_deg))
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def camera_rays(camera: CameraModel, supersample: int) -> tuple[np.ndarray, np.ndarray]:
    """Normalised undistorted coordinates (H·s·W·s, 1, 2) float32 of every supersampled pixel,
    and the corners (4,2) of their bounding box.

    Cached per camera: undistorting a million points is the slow part of rendering.
    """
    key = (camera.K.tobytes(), camera.dist.tobytes(), camera.image_size, supersample)
    if key in _RAY_CACHE:
        return _RAY_CACHE[key]
    width, height = camera.image_size
    s = supersample
    # Supersampled pixel (i, j) is camera pixel ((i - (s-1)/2) / s, ...): centres stay aligned.
    xs = (np.arange(width * s) - (s - 1) / 2.0) / s
    ys = (np.arange(height * s) - (s - 1) / 2.0) / s
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    rays = camera.undistort_normalized(grid).astype(np.float32).reshape(-1, 1, 2)
    lo, hi = rays.reshape(-1, 2).min(axis=0), rays.reshape(-1, 2).max(axis=0)
    box = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [lo[0], hi[1]], [hi[0], hi[1]]], np.float64)
    if len(_RAY_CACHE) > 8:
        _RAY_CACHE.clear()
    _RAY_CACHE[key] = (rays, box)
    return rays, box


def render_plane(
    texture: np.ndarray,
    tex_from_plane: np.ndarray,
    camera: CameraModel,
    cam_T_plane: np.ndarray,
    supersample: int = 2,
) -> tuple[np.ndarray, np.ndarray]:
    """Render a planar texture (z = 0 plane of ``cam_T_plane``) into ``camera``.

    Returns the image (H,W) float32 in texture units and the coverage (H,W) float32 in [0, 1].
    """
    width, height = camera.image_size
    s = supersample
    rays, box = camera_rays(camera, s)
    Hn = np.column_stack([cam_T_plane[:3, 0], cam_T_plane[:3, 1], cam_T_plane[:3, 3]])
    M = tex_from_plane @ np.linalg.inv(Hn)
    # Rays that meet the plane behind the camera have w ≤ 0; w is linear in the ray, so checking
    # the extremes of the ray bundle is enough to take the fast path.
    if np.all(box @ M[2, :2] + M[2, 2] > 1e-9):
        maps = np.asarray(cv2.perspectiveTransform(rays, M.astype(np.float64)), np.float32).reshape(
            height * s, width * s, 2
        )
    else:
        q = rays.reshape(-1, 2).astype(np.float64) @ M[:, :2].T + M[:, 2]
        front = q[:, 2] > 1e-9
        xy = np.where(front[:, None], q[:, :2] / np.where(front, q[:, 2], 1.0)[:, None], -1e6)
        maps = xy.astype(np.float32).reshape(height * s, width * s, 2)
    layers = np.dstack([texture.astype(np.float32), np.ones(texture.shape[:2], np.float32)])
    no_map2 = cast(Any, None)  # the stubs demand map2; OpenCV takes None with a 2-channel map1
    out = cv2.remap(layers, maps, no_map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    if s > 1:
        out = cv2.resize(out, (width, height), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(out[..., 0]), np.ascontiguousarray(out[..., 1])


@dataclass(frozen=True)
class RenderNoise:
    """Image degradations: Gaussian pixel noise (grey levels), optical blur (px), background."""

    pixel_std: float = 2.0
    blur_sigma_px: float = 0.5
    background: float = 110.0

    def __post_init__(self) -> None:
        if self.pixel_std < 0 or self.blur_sigma_px < 0 or not 0 <= self.background <= 255:
            raise ValueError(f"invalid render noise {self}")


def compose(
    layers: list[tuple[np.ndarray, np.ndarray]],
    size: tuple[int, int],
    noise: RenderNoise,
    rng: np.random.Generator,
) -> np.ndarray:
    """Alpha-composite rendered planes (first is at the back), blur, add noise → uint8 image."""
    width, height = size
    out = np.full((height, width), noise.background, np.float32)
    for img, cover in layers:
        out = out * (1.0 - cover) + img * cover
    if noise.blur_sigma_px > 0:
        out = np.asarray(cv2.GaussianBlur(out, (0, 0), noise.blur_sigma_px), np.float32)
    if noise.pixel_std > 0:
        out = out + rng.normal(0.0, noise.pixel_std, out.shape).astype(np.float32)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def render_board(
    board: BoardSpec,
    camera: CameraModel,
    cam_T_board: np.ndarray,
    rng: np.random.Generator,
    noise: RenderNoise | None = None,
    px_per_square: int = 48,
    supersample: int = 2,
) -> np.ndarray:
    """A grayscale uint8 image of ``board`` at ``cam_T_board`` (board units = metres here)."""
    texture, tex_from_board = board.texture(px_per_square)
    layer = render_plane(texture, tex_from_board, camera, cam_T_board, supersample)
    return compose([layer], camera.image_size, noise or RenderNoise(), rng)


def marker_texture(
    dictionary: str, marker_id: int, marker_length_m: float, px: int = 120
) -> tuple[np.ndarray, np.ndarray]:
    """An ArUco marker with a white quiet zone, and the map from marker-frame metres to pixels.

    The marker frame is OpenCV's: origin at the centre, x right, y up, z out of the marker.
    """
    img = cv2.aruco.generateImageMarker(aruco_dictionary(dictionary), marker_id, px, borderBits=1)
    margin = px // 4
    tex = np.full((px + 2 * margin, px + 2 * margin), 255, np.uint8)
    tex[margin : margin + px, margin : margin + px] = img
    scale = px / marker_length_m
    centre = margin + px / 2.0 - 0.5
    tex_from_marker = np.array([[scale, 0, centre], [0, -scale, centre], [0, 0, 1.0]])
    return tex, tex_from_marker


def project_board(
    board: BoardSpec,
    camera: CameraModel,
    cam_T_board: np.ndarray,
    noise_px: float,
    rng: np.random.Generator,
) -> Detection | None:
    """Project every board corner with ``cv2.projectPoints`` and add Gaussian noise (px).

    Returns ``None`` when a corner falls outside the image or behind the camera.
    """
    obj = board.object_points().astype(np.float64)
    cam_p = obj @ cam_T_board[:3, :3].T + cam_T_board[:3, 3]
    if np.any(cam_p[:, 2] <= 0):
        return None
    uv = camera.project(cam_p) + rng.normal(0.0, noise_px, (len(obj), 2))
    width, height = camera.image_size
    if np.any(uv < 0) or np.any(uv[:, 0] > width - 1) or np.any(uv[:, 1] > height - 1):
        return None
    return Detection(
        uv.astype(np.float32), obj.astype(np.float32), np.arange(len(obj), dtype=np.int32)
    )


def random_board_poses(
    board: BoardSpec,
    cameras: list[tuple[CameraModel, np.ndarray]],
    count: int,
    rng: np.random.Generator,
    distance_m: tuple[float, float] = (0.35, 0.75),
    max_tilt_deg: float = 35.0,
    margin_px: float = 25.0,
) -> list[np.ndarray]:
    """Board poses ``ref_T_board`` seen whole by every camera, varied in tilt, roll and position.

    ``cameras`` holds each camera with its ``cam_T_ref`` (identity for the reference camera).
    """
    obj = board.object_points().astype(np.float64)
    centre = obj.mean(axis=0)
    poses: list[np.ndarray] = []
    for _ in range(count * 500):
        if len(poses) == count:
            break
        R = rotation(
            rng.uniform(-max_tilt_deg, max_tilt_deg),
            rng.uniform(-max_tilt_deg, max_tilt_deg),
            rng.uniform(-25.0, 25.0),
        )
        ref_camera = cameras[0][0]
        z = rng.uniform(*distance_m)
        u = rng.uniform(0.15, 0.85) * ref_camera.image_size[0]
        v = rng.uniform(0.15, 0.85) * ref_camera.image_size[1]
        ray = ref_camera.undistort_normalized(np.array([[u, v]]))[0]
        t = np.array([ray[0] * z, ray[1] * z, z]) - R @ centre
        ref_T_board = pose(R, t)
        ok = True
        for camera, cam_T_ref in cameras:
            cam_T_board = cam_T_ref @ ref_T_board
            cam_p = obj @ cam_T_board[:3, :3].T + cam_T_board[:3, 3]
            if np.any(cam_p[:, 2] <= 0.05) or cam_T_board[2, 2] < 0.3:  # must face the camera
                ok = False
                break
            uv = camera.project(cam_p)
            w, h = camera.image_size
            if (
                np.any(uv < margin_px)
                or np.any(uv[:, 0] > w - margin_px)
                or np.any(uv[:, 1] > h - margin_px)
            ):
                ok = False
                break
        if ok:
            poses.append(ref_T_board)
    if len(poses) < count:
        raise ValueError(f"found only {len(poses)} of {count} board poses inside the image")
    return poses


def render_marker(
    camera: CameraModel,
    cam_T_marker: np.ndarray,
    rng: np.random.Generator,
    dictionary: str = "DICT_4X4_50",
    marker_id: int = 0,
    marker_length_m: float = 0.04,
    noise: RenderNoise | None = None,
    supersample: int = 2,
) -> np.ndarray:
    """A grayscale uint8 image of one ArUco marker (with its white quiet zone)."""
    texture, tex_from_marker = marker_texture(dictionary, marker_id, marker_length_m)
    layer = render_plane(texture, tex_from_marker, camera, cam_T_marker, supersample)
    return compose([layer], camera.image_size, noise or RenderNoise(), rng)


def facing_camera(rx_deg: float = 0.0, ry_deg: float = 0.0, rz_deg: float = 0.0) -> np.ndarray:
    """A marker rotation (3×3) that faces an OpenCV camera (marker z towards it), then tilted."""
    return rotation(rx_deg, ry_deg, rz_deg) @ rotation(180.0, 0.0, 0.0)


def example_rig() -> StereoRig:
    """The stereo rig the tests and benches use as ground truth: two slightly different
    640×480 cameras with real-looking distortion, 9 cm apart, a little toed in."""
    left = CameraModel(
        K=np.array([[612.0, 0.0, 318.5], [0.0, 608.0, 242.0], [0.0, 0.0, 1.0]]),
        dist=np.array([-0.14, 0.09, 0.0007, -0.0005, 0.0]),
        image_size=(640, 480),
        name="left",
    )
    right = CameraModel(
        K=np.array([[605.0, 0.0, 322.0], [0.0, 603.0, 237.5], [0.0, 0.0, 1.0]]),
        dist=np.array([-0.12, 0.07, -0.0004, 0.0006, 0.0]),
        image_size=(640, 480),
        name="right",
    )
    return StereoRig(left, right, rotation(0.4, -2.5, 0.3), np.array([-0.09, 0.0015, 0.001]))
