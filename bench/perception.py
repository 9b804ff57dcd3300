"""Perception figures: triangulation accuracy, Kalman tracking quality and per-frame speed.

Prints one JSON object per line: ``metric``, ``value``, ``unit``, ``target`` and ``pass``.

Set-up: the synthetic rig ``calibration.synthetic.example_rig`` (640×480, f ≈ 610 px, 9 cm
baseline, real distortion), a 4 cm ArUco marker (DICT_4X4_50) about 0.5 m away, and an arm
base frame rotated and shifted from the left camera.

- Triangulation: marker corners projected with OpenCV plus 0.2 px noise (``points``), and
  rendered images with real ArUco detection (``images``); RMS 3-D error of the marker centre.
- Kalman: measurements from the same stereo error model (corners + 0.2 px → triangulate → pose
  → base frame) at 20 Hz. Static jitter reduction (raw RMS / filtered RMS about the truth),
  injected 3 cm outliers rejected, and a 0.1 m amplitude, 0.3 Hz sinusoid followed for 60 s
  without re-initialisation or loss.
- Speed: ``StereoMarkerTracker.observe`` (detect both images, triangulate, fit the pose, filter)
  on pre-rendered 640×480 frame pairs, pinned to one core with OpenCV single-threaded. The
  reference measured in the same run is bare ``ArucoDetector.detectMarkers`` on both frames.

Run: ``.venv/bin/python bench/perception.py``
"""

from __future__ import annotations

import os

# "One core": BLAS single-threaded too (set before numpy loads); OpenCV and affinity in speed().
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from support.load import emit_row  # noqa: E402

from calibration.boards import aruco_dictionary  # noqa: E402
from calibration.kalman import KalmanTracker, TrackerConfig  # noqa: E402
from calibration.markers import marker_corners  # noqa: E402
from calibration.perception import StereoMarkerTracker  # noqa: E402
from calibration.synthetic import (  # noqa: E402
    RenderNoise,
    example_rig,
    facing_camera,
    pose,
    render_marker,
    rotation,
)
from calibration.triangulate import StereoRig, fit_marker_pose  # noqa: E402

LENGTH_M = 0.04
NOISE_PX = 0.2
RATE_HZ = 20.0
BASE_T_CAM = pose(rotation(-115.0, 2.0, 88.0), [0.30, -0.02, 0.45])


def emit(
    metric: str, value: float, unit: str, target: str, passed: bool | None, **extra: object
) -> None:
    row: dict[str, object] = {"metric": metric, "value": round(float(value), 6), "unit": unit}
    row.update(target=target, **{"pass": passed}, **extra)
    emit_row(row)


class NoisyStereo:
    """The stereo error model: true marker pose → noisy corners → triangulated base-frame pose."""

    def __init__(self, rig: StereoRig, rng: np.random.Generator) -> None:
        self.rig, self.rng = rig, rng
        self.model = marker_corners(LENGTH_M)

    def corners(self, left_T_marker: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        left_p = self.model @ left_T_marker[:3, :3].T + left_T_marker[:3, 3]
        uv_l = self.rig.left.project(left_p) + self.rng.normal(0, NOISE_PX, (4, 2))
        uv_r = self.rig.right.project(left_p @ self.rig.R.T + self.rig.T)
        return uv_l, uv_r + self.rng.normal(0, NOISE_PX, (4, 2))

    def measure(self, left_T_marker: np.ndarray) -> np.ndarray:
        """Base-frame position of the marker centre (3,), as StereoMarkerTracker computes it."""
        cam_corners = self.rig.triangulate(*self.corners(left_T_marker))
        cam_T_marker, _ = fit_marker_pose(cam_corners, self.model)
        return (BASE_T_CAM @ cam_T_marker)[:3, 3]


def random_marker_pose(rng: np.random.Generator, depth_m: float = 0.5) -> np.ndarray:
    R = facing_camera(rng.uniform(-30, 30), rng.uniform(-30, 30), rng.uniform(-180, 180))
    return pose(R, [rng.uniform(-0.08, 0.08), rng.uniform(-0.06, 0.06), depth_m])


def triangulation(rig: StereoRig) -> None:
    rng = np.random.default_rng(0)
    noisy = NoisyStereo(rig, rng)
    errors, corner_errors = [], []
    for _ in range(2000):
        T = random_marker_pose(rng)
        uv_l, uv_r = noisy.corners(T)
        cam_corners = rig.triangulate(uv_l, uv_r)
        truth = noisy.model @ T[:3, :3].T + T[:3, 3]
        corner_errors.extend(np.linalg.norm(cam_corners - truth, axis=1))
        errors.append(np.linalg.norm(cam_corners.mean(axis=0) - T[:3, 3]))
    rms_mm = 1000 * math.sqrt(float(np.mean(np.square(errors))))
    corner_mm = 1000 * math.sqrt(float(np.mean(np.square(corner_errors))))
    emit("triangulation_rms_points", rms_mm, "mm", "<= 2 at 0.5 m", rms_mm <= 2.0,
         samples=2000, per_corner_rms_mm=round(corner_mm, 3), noise=f"{NOISE_PX} px")  # fmt: skip

    errors = []
    tracker = StereoMarkerTracker(rig, marker_id=0, marker_length_m=LENGTH_M, roi_margin=0)
    missed = 0
    for _ in range(40):
        T = random_marker_pose(rng)
        frames = [
            render_marker(cam, X @ T, rng, marker_length_m=LENGTH_M, noise=RenderNoise(2.0, 0.6))
            for cam, X in ((rig.left, np.eye(4)), (rig.right, rig.right_T_left))
        ]
        meas = tracker.measure(*frames)
        if meas is None:
            missed += 1
            continue
        errors.append(np.linalg.norm(meas.position_m - T[:3, 3]))
    rms_mm = 1000 * math.sqrt(float(np.mean(np.square(errors))))
    emit("triangulation_rms_images", rms_mm, "mm", "<= 2 at 0.5 m", rms_mm <= 2.0,
         samples=len(errors), missed=missed)  # fmt: skip


def kalman(rig: StereoRig) -> None:
    dt = 1.0 / RATE_HZ
    rng = np.random.default_rng(1)
    noisy = NoisyStereo(rig, rng)
    still = pose(facing_camera(10, -15, 20), [0.02, -0.01, 0.5])
    truth = (BASE_T_CAM @ still)[:3, 3]
    # The filter is told the measurement noise, measured beforehand like a user would.
    sigma_m = float(np.std([noisy.measure(still) for _ in range(400)], axis=0).max())
    config = TrackerConfig(measurement_std_m=sigma_m)

    tracker = KalmanTracker(config)
    raw, filtered = [], []
    for k in range(1200):
        z = noisy.measure(still)
        est = tracker.update(z, k * dt)
        if k >= 100:  # after convergence
            raw.append(z - truth)
            filtered.append(est.position_m - truth)
    raw_rms = math.sqrt(float(np.mean(np.sum(np.square(raw), axis=1))))
    flt_rms = math.sqrt(float(np.mean(np.sum(np.square(filtered), axis=1))))
    ratio = raw_rms / flt_rms
    emit("kalman_static_jitter_reduction", ratio, "x", ">= 1.5", ratio >= 1.5,
         raw_rms_mm=round(1000 * raw_rms, 3), filtered_rms_mm=round(1000 * flt_rms, 3),
         measurement_std_mm=round(1000 * sigma_m, 3), rate_hz=RATE_HZ)  # fmt: skip

    # 0.1 m amplitude, 0.3 Hz along the base x axis, with 3 cm outliers on every 10th frame.
    base_T_left = BASE_T_CAM
    left_T_base = np.linalg.inv(base_T_left)
    tracker = KalmanTracker(config)
    injected = rejected = false_rejections = 0
    errors = []
    for k in range(int(60 * RATE_HZ)):
        t = k * dt
        base_p = truth + np.array([0.1 * math.sin(2 * math.pi * 0.3 * t), 0.0, 0.0])
        left_T_marker = pose(still[:3, :3], left_T_base[:3, :3] @ base_p + left_T_base[:3, 3])
        z = noisy.measure(left_T_marker)
        outlier = k > 40 and k % 10 == 5
        if outlier:
            direction = rng.normal(size=3)
            z = z + 0.03 * direction / np.linalg.norm(direction)
            injected += 1
        est = tracker.update(z, t)
        if est.status == "rejected":
            rejected += outlier
            false_rejections += not outlier
        if k >= 40:
            errors.append(np.linalg.norm(est.position_m - base_p))
    rate = 100.0 * rejected / injected
    emit("kalman_outliers_rejected", rate, "%", "100", rate == 100.0, injected=injected,
         outlier_m=0.03)  # fmt: skip
    lost = tracker.stats.reinitialised + tracker.stats.lost
    emit("kalman_motion_lock_losses", lost, "count", "0", lost == 0,
         motion="0.1 m amplitude, 0.3 Hz, 60 s", false_rejections=false_rejections,
         rms_error_mm=round(1000 * math.sqrt(float(np.mean(np.square(errors)))), 3),
         max_error_mm=round(1000 * float(np.max(errors)), 3))  # fmt: skip


def speed(rig: StereoRig) -> None:
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    cv2.setNumThreads(1)
    rng = np.random.default_rng(2)
    noise = RenderNoise(2.0, 0.6)
    frames = []
    n_frames = 40  # one period of a smooth motion, so the laps join up without a jump
    for k in range(n_frames):
        phase = 2 * math.pi * k / n_frames
        T = pose(facing_camera(15 * math.sin(phase), 10, 20 * math.cos(phase)),
                 [0.08 * math.sin(phase), 0.02 * math.cos(phase), 0.5])  # fmt: skip
        frames.append(tuple(
            cv2.cvtColor(render_marker(cam, X @ T, rng, marker_length_m=LENGTH_M, noise=noise),
                         cv2.COLOR_GRAY2BGR)
            for cam, X in ((rig.left, np.eye(4)), (rig.right, rig.right_T_left))
        ))  # fmt: skip
    detector = cv2.aruco.ArucoDetector(aruco_dictionary("DICT_4X4_50"))
    trackers = {
        label: StereoMarkerTracker(
            rig, BASE_T_CAM, marker_id=0, marker_length_m=LENGTH_M, roi_margin=margin
        )
        for label, margin in (("roi", 1.5), ("full_frame", 0.0))
    }
    # Interleaved per frame, so the reference and both variants see the same machine load.
    times: dict[str, list[float]] = {"reference": [], **{label: [] for label in trackers}}
    updated = dict.fromkeys(trackers, 0)
    laps = 5
    for lap in range(laps):
        for k, (fl, fr) in enumerate(frames):
            t0 = time.perf_counter()
            detector.detectMarkers(fl)
            detector.detectMarkers(fr)
            times["reference"].append(time.perf_counter() - t0)
            for label, tracker in trackers.items():
                t0 = time.perf_counter()
                est = tracker.observe(fl, fr, (lap * len(frames) + k) / RATE_HZ)
                times[label].append(time.perf_counter() - t0)
                updated[label] += est.status == "updated"
    ref_ms = 1000 * float(np.median(times["reference"]))
    for label in trackers:
        med = 1000 * float(np.median(times[label]))
        emit(f"observe_ms_{label}", med, "ms", "<= 10 (one core)", med <= 10.0,
             p95_ms=round(1000 * float(np.percentile(times[label], 95)), 3),
             ratio_to_bare_detection=round(med / ref_ms, 3), bare_detection_ms=round(ref_ms, 3),
             frames=len(times[label]), updated=updated[label], image="640x480 BGR")  # fmt: skip


def main() -> int:
    rig = example_rig()
    triangulation(rig)
    kalman(rig)
    speed(rig)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
