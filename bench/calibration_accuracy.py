"""Calibration accuracy on synthetic ground truth and on the real 25-pair data set.

Prints one JSON object per line: ``metric``, ``value``, ``unit``, ``target`` and ``pass``.

Synthetic: two 640×480 cameras with known K, distortion and a 9 cm baseline; a 9×6 chessboard
(25 mm squares) at 25 random poses (0.3–0.6 m, tilts up to 45°); figures are the worst over
several independent sets. Two measurement paths:
- ``points``: corners projected with ``cv2.projectPoints`` plus 0.2 px Gaussian noise;
- ``images``: boards rendered into images (blur, pixel noise) and detected with OpenCV.
Real: ``tests/data/stereo_chessboard_9x6`` (square size unknown, so only px figures and the
agreement with plain OpenCV are reported).

Run: ``.venv/bin/python bench/calibration_accuracy.py``
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from support.load import emit_row  # noqa: E402

from calibration.boards import parse_board  # noqa: E402
from calibration.dataset import detect_images, list_images, pair_images  # noqa: E402
from calibration.stereo import StereoPair, calibrate_stereo  # noqa: E402
from calibration.synthetic import (  # noqa: E402
    RenderNoise,
    example_rig,
    project_board,
    random_board_poses,
    render_board,
)

N_VIEWS = 25  # tilted up to 45° at 0.3–0.6 m, as a calibration guide would ask
NOISE_PX = 0.2


def emit(
    metric: str, value: float, unit: str, target: str, passed: bool | None, **extra: object
) -> None:
    row = {"metric": metric, "value": round(float(value), 6), "unit": unit, "target": target}
    row["pass"] = passed
    row.update(extra)
    emit_row(row)


def synthetic(path: str, seeds: range) -> None:
    """Worst focal and baseline error over the seeds (each a fresh set of 20 views)."""
    rows = [_synthetic_once(path, seed) for seed in seeds]
    f_err = max(r[0] for r in rows)
    b_err = max(r[1] for r in rows)
    rms = max(r[2] for r in rows)
    extra = {"views": N_VIEWS, "runs": len(rows),
             "noise": f"{NOISE_PX} px" if path == "points" else "rendered images"}  # fmt: skip
    emit(f"focal_error_{path}", 100 * f_err, "%", "<= 0.5", 100 * f_err <= 0.5, **extra)
    emit(f"baseline_error_{path}", 100 * b_err, "%", "<= 0.5", 100 * b_err <= 0.5, **extra)
    emit(f"stereo_rms_{path}", rms, "px", "< 0.5", rms < 0.5, runs=len(rows))


def _synthetic_once(path: str, seed: int) -> tuple[float, float, float]:
    rig = example_rig()
    board = parse_board("chessboard:9x6:0.025")
    rng = np.random.default_rng(seed)
    cams = [(rig.left, np.eye(4)), (rig.right, rig.right_T_left)]
    poses = random_board_poses(board, cams, N_VIEWS, rng, distance_m=(0.3, 0.6), max_tilt_deg=45.0)
    pairs = []
    for i, left_T_board in enumerate(poses):
        right_T_board = rig.right_T_left @ left_T_board
        if path == "points":
            dl = project_board(board, rig.left, left_T_board, NOISE_PX, rng)
            dr = project_board(board, rig.right, right_T_board, NOISE_PX, rng)
        else:
            noise = RenderNoise(pixel_std=2.0, blur_sigma_px=0.6)
            dl = board.detect(render_board(board, rig.left, left_T_board, rng, noise))
            dr = board.detect(render_board(board, rig.right, right_T_board, rng, noise))
        pairs.append(StereoPair(f"{i:02d}", dl, dr))
    res = calibrate_stereo(pairs, board, (640, 480))
    f_err = max(
        abs(cam.fx / true.fx - 1)
        for cam, true in ((res.rig.left, rig.left), (res.rig.right, rig.right))
    )
    f_err = max(
        f_err,
        *(
            abs(cam.fy / true.fy - 1)
            for cam, true in ((res.rig.left, rig.left), (res.rig.right, rig.right))
        ),
    )
    b_err = abs(res.rig.baseline / rig.baseline - 1)
    return f_err, b_err, res.rms_px


def real_data() -> None:
    data = REPO / "tests" / "data" / "stereo_chessboard_9x6"
    board = parse_board("chessboard:9x6:1")
    t0 = time.perf_counter()
    paths = list_images(data)
    pairs = pair_images(paths, paths)
    det_l = detect_images(board, [p[1] for p in pairs])
    det_r = detect_images(board, [p[2] for p in pairs])
    stereo = [
        StereoPair(k, a, b)
        for (k, _, _), a, b in zip(pairs, det_l.detections, det_r.detections, strict=True)
    ]
    res = calibrate_stereo(stereo, board, det_l.image_size)
    elapsed = time.perf_counter() - t0
    for mono in (res.left, res.right):
        name = mono.camera.name
        emit(f"real_mono_rms_{name}", mono.rms_px, "px", "< 0.5", mono.rms_px < 0.5,
             views=mono.views_used, sigma_fx_px=round(mono.std["fx"], 3))  # fmt: skip
    emit("real_stereo_rms", res.rms_px, "px", "< 0.5", res.rms_px < 0.5, pairs=res.views_used,
         rejected=res.views_rejected)  # fmt: skip
    emit("real_epipolar_rms", res.epipolar_rms_px, "px", "< 0.5", res.epipolar_rms_px < 0.5)
    emit("real_baseline", res.rig.baseline, "squares", "n/a", None)
    emit("real_stereo_calibration_time", elapsed, "s", "n/a", None, images=50)


def main() -> int:
    synthetic("points", range(1, 6))
    synthetic("images", range(100, 102))
    real_data()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
