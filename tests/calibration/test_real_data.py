"""The 25 real stereo pairs (640×512, 9×6 inner corners, square size unknown: 1 unit).

Our CLI's results are compared with plain OpenCV run here directly (findChessboardCorners,
cornerSubPix, calibrateCamera, stereoCalibrate) on the same views: RMS and baseline within 2%.
"""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml

from calibration.triangulate import StereoRig

BOARD = "chessboard:9x6:1"
SIZE = (640, 512)
_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)


def _plain_opencv_corners(path: Path) -> np.ndarray:
    gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(gray, (9, 6), flags=flags)
    assert found, path
    return cv2.cornerSubPix(gray, corners, (7, 7), (-1, -1), _CRITERIA)


@pytest.fixture(scope="session")
def reference(data_dir: Path) -> dict[str, dict[str, np.ndarray]]:
    """Corners found by plain OpenCV in every image, keyed by side then pair name."""
    out: dict[str, dict[str, np.ndarray]] = {}
    for side in ("left", "right"):
        paths = sorted(data_dir.glob(f"{side}*.jpg"))
        with ThreadPoolExecutor(2) as pool:
            corners = list(pool.map(_plain_opencv_corners, paths))
        out[side] = {p.stem.replace(side, ""): c for p, c in zip(paths, corners, strict=True)}
    return out


def _objp(n: int) -> list[np.ndarray]:
    obj = np.zeros((54, 3), np.float32)
    obj[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2)
    return [obj] * n


@pytest.fixture(scope="session")
def stereo_run(
    tmp_path_factory: pytest.TempPathFactory, data_dir: Path, run_cli: Any
) -> tuple[dict[str, Any], Path]:
    out = tmp_path_factory.mktemp("real_stereo")
    code, stdout, stderr = run_cli(
        "stereo",
        "--left",
        str(data_dir),
        "--right",
        str(data_dir),
        "--board",
        BOARD,
        "--out",
        str(out),
        "--json",
    )
    assert code == 0, stderr
    return json.loads(stdout), out


def test_mono_matches_plain_opencv(
    tmp_path: Path, data_dir: Path, run_cli: Any, reference: dict
) -> None:
    code, stdout, stderr = run_cli(
        "intrinsics",
        "--images",
        str(data_dir / "left*.jpg"),
        "--board",
        BOARD,
        "--out",
        str(tmp_path),
        "--json",
        "--name",
        "left",
    )
    assert code == 0, stderr
    summary = json.loads(stdout)
    used = sorted(k.replace("left", "").replace(".jpg", "") for k in summary["per_view_rms_px"])
    assert summary["views_used"] == len(used) >= 20
    assert summary["views_used"] + summary["views_rejected"] == 25
    rms, K, *_ = cv2.calibrateCamera(
        _objp(len(used)), [reference["left"][k] for k in used], SIZE, None, None
    )
    assert summary["rms_px"] == pytest.approx(rms, rel=0.02)
    assert summary["fx"] == pytest.approx(K[0, 0], rel=0.02)
    assert summary["rms_px"] < 0.5 and not summary["warnings"]
    for key in ("fx", "fy", "cx", "cy"):
        assert 0 < summary["sigma"][key] < 3.0
    assert {"fx_px", "heldout_rms_px"} <= set(summary["cross_validation"])
    for name in ("camera.yaml", "camera_info.yaml", "report.md", "report.png", "summary.json"):
        assert (tmp_path / name).is_file(), name


def test_stereo_matches_plain_opencv(stereo_run: tuple[dict, Path], reference: dict) -> None:
    summary, _ = stereo_run
    used = sorted(summary["per_pair_rms_px"])
    assert summary["views_used"] == len(used) >= 20
    assert summary["views_used"] + summary["views_rejected"] == 25
    ref_l, ref_r = reference["left"], reference["right"]
    everything = sorted(ref_l)
    _, K1, D1, _, _ = cv2.calibrateCamera(
        _objp(25), [ref_l[k] for k in everything], SIZE, None, None
    )
    _, K2, D2, _, _ = cv2.calibrateCamera(
        _objp(25), [ref_r[k] for k in everything], SIZE, None, None
    )
    rms, *_, T, _, _ = cv2.stereoCalibrate(
        _objp(len(used)),
        [ref_l[k] for k in used],
        [ref_r[k] for k in used],
        K1,
        D1,
        K2,
        D2,
        SIZE,
        flags=cv2.CALIB_FIX_INTRINSIC,
    )
    assert summary["rms_px"] == pytest.approx(rms, rel=0.02)
    assert summary["baseline"] == pytest.approx(float(np.linalg.norm(T)), rel=0.02)
    for side in ("left", "right"):
        for key in ("fx", "fy", "cx", "cy", "rms_px"):
            assert key in summary[side]
    assert summary["left"]["fx"] == pytest.approx(K1[0, 0], rel=0.02)
    assert summary["epipolar_rms_px"] < 0.3


def test_stereo_outputs_are_readable(stereo_run: tuple[dict, Path]) -> None:
    summary, out = stereo_run
    fs = cv2.FileStorage(str(out / "stereo.yaml"), cv2.FILE_STORAGE_READ)
    for key in ("K1", "D1", "K2", "D2", "R", "T", "E", "F", "R1", "R2", "P1", "P2", "Q"):
        assert fs.getNode(key).mat() is not None, key
    T = fs.getNode("T").mat().ravel()
    fs.release()
    assert np.linalg.norm(T) == pytest.approx(summary["baseline"])
    rig = StereoRig.load(out / "stereo.yaml")
    assert rig.baseline == pytest.approx(summary["baseline"])
    for side in ("left", "right"):
        doc = yaml.safe_load((out / f"{side}_camera_info.yaml").read_text())
        assert doc["camera_name"] == side and doc["image_height"] == 512
        assert len(doc["projection_matrix"]["data"]) == 12
    assert "Stereo pairs" in (out / "report.md").read_text()
    png = cv2.imdecode(np.frombuffer((out / "report.png").read_bytes(), np.uint8), 1)
    assert png is not None and png.shape[0] > 500
    assert json.loads((out / "summary.json").read_text())["baseline"] == summary["baseline"]


def test_check_measures_the_board(
    stereo_run: tuple[dict, Path], data_dir: Path, run_cli: Any
) -> None:
    _, out = stereo_run
    code, stdout, stderr = run_cli(
        "check",
        "--calib",
        str(out / "stereo.yaml"),
        "--left",
        str(data_dir),
        "--right",
        str(data_dir),
        "--board",
        BOARD,
        "--json",
    )
    assert code == 0, stderr
    result = json.loads(stdout)
    assert abs(result["square_size_error_pct"]) < 1.0
    assert result["epipolar_rms_px"] < 0.3
    assert result["pairs_used"] == 25 and result["passed"] is True
    # nine of the pairs against a board said to be 2% bigger: the check must fail
    code, stdout, _ = run_cli(
        "check",
        "--calib",
        str(out / "stereo.yaml"),
        "--left",
        str(data_dir / "left0*.jpg"),
        "--right",
        str(data_dir / "right0*.jpg"),
        "--board",
        "chessboard:9x6:1.02",
    )
    assert code == 1 and "FAIL" in stdout
