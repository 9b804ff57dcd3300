"""Kabsch/Umeyama registration of the camera to the arm, its residuals and the CLI."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from calibration.errors import RegistrationError
from calibration.registration import load_base_T_cam, register, transform_points, umeyama
from calibration.synthetic import facing_camera, pose, render_marker, rotation
from calibration.triangulate import StereoRig, quaternion_from_matrix


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(4, 30), scale=st.floats(0.5, 2.0))
def test_umeyama_recovers_any_similarity(seed: int, n: int, scale: float) -> None:
    rng = np.random.default_rng(seed)
    R = _random_rotation(rng)
    t = rng.uniform(-1, 1, 3)
    src = rng.uniform(-0.3, 0.3, (n, 3))
    dst = scale * src @ R.T + t
    R_fit, t_fit, s_fit = umeyama(src, dst, with_scale=True)
    np.testing.assert_allclose(R_fit, R, atol=1e-8)
    np.testing.assert_allclose(t_fit, t, atol=1e-8)
    assert s_fit == pytest.approx(scale)
    assert np.linalg.det(R_fit) == pytest.approx(1.0)


def test_planar_points_never_give_a_reflection() -> None:
    rng = np.random.default_rng(1)
    src = np.column_stack([rng.uniform(-0.2, 0.2, (6, 2)), np.zeros(6)])
    R = rotation(20, -30, 50)
    dst = src @ R.T + [0.1, 0.2, 0.3] + rng.normal(0, 1e-4, (6, 3))
    R_fit, _, _ = umeyama(src, dst)
    assert np.linalg.det(R_fit) == pytest.approx(1.0)
    assert np.abs(R_fit - R).max() < 0.01


def test_register_reports_residuals_and_flags_a_bad_point() -> None:
    rng = np.random.default_rng(2)
    base_T_cam = pose(rotation(100, 5, -30), [0.3, -0.1, 0.6])
    cam_p = np.column_stack([rng.uniform(-0.1, 0.1, (8, 2)), rng.uniform(0.4, 0.6, 8)])
    base_p = transform_points(base_T_cam, cam_p) + rng.normal(0, 0.0005, (8, 3))
    reg = register(cam_p, base_p, [f"p{i}" for i in range(8)])
    np.testing.assert_allclose(reg.base_T_cam, base_T_cam, atol=0.01)
    assert reg.rms_m < 0.0015
    base_p[3] += [0.02, 0, 0]  # the arm was not where it said
    bad = register(cam_p, base_p, [f"p{i}" for i in range(8)])
    assert int(np.argmax(bad.residuals_m)) == 3
    assert bad.summary()["residuals_m"]["p3"] == pytest.approx(bad.max_m)


@pytest.mark.parametrize(
    ("cam", "base", "fragment"),
    [
        (np.zeros((3, 3)), np.zeros((3, 3)), "at least 4 correspondences"),
        (np.zeros((4, 3)), np.zeros((5, 3)), "4 camera points but 5 arm points"),
        (np.outer(np.arange(5), [1.0, 0, 0]), np.outer(np.arange(5), [0, 1.0, 0]), "collinear"),
        (np.full((4, 3), np.nan), np.zeros((4, 3)), "NaN"),
    ],
)
def test_register_refuses_bad_input(cam: np.ndarray, base: np.ndarray, fragment: str) -> None:
    with pytest.raises(RegistrationError, match=fragment):
        register(cam, base)


def test_cli_register_from_points(tmp_path: Path, run_cli: Any) -> None:
    rng = np.random.default_rng(3)
    base_T_cam = pose(rotation(-120, 0, 90), [0.25, 0.0, 0.45])
    cam_p = np.column_stack([rng.uniform(-0.1, 0.1, (6, 2)), rng.uniform(0.35, 0.6, 6)])
    base_p = transform_points(base_T_cam, cam_p)
    rows = ["name,cam_x,cam_y,cam_z,base_x,base_y,base_z"] + [
        f"pose{i}," + ",".join(f"{v:.9f}" for v in (*c, *b))
        for i, (c, b) in enumerate(zip(cam_p, base_p, strict=True))
    ]
    (tmp_path / "points.csv").write_text("\n".join(rows) + "\n")
    code, stdout, stderr = run_cli(
        "register", "--points", str(tmp_path / "points.csv"), "--out", str(tmp_path), "--json"
    )
    assert code == 0, stderr
    summary = json.loads(stdout)
    assert summary["points"] == 6 and summary["rms_m"] < 1e-6
    np.testing.assert_allclose(load_base_T_cam(tmp_path / "base_T_cam.yaml"), base_T_cam, atol=1e-6)


def test_cli_register_from_marker_images(tmp_path: Path, run_cli: Any, rig: StereoRig) -> None:
    """The arm carries a marker to six known base positions; both cameras photograph it."""
    base_T_cam = pose(rotation(-110, 3, 85), [0.28, -0.02, 0.42])
    cam_T_base = np.linalg.inv(base_T_cam)
    rng = np.random.default_rng(4)
    for side in ("left", "right"):
        (tmp_path / side).mkdir()
    rows = ["name,base_x,base_y,base_z"]
    for i in range(6):
        left_p = np.array(
            [rng.uniform(-0.08, 0.08), rng.uniform(-0.06, 0.06), rng.uniform(0.4, 0.55)]
        )
        left_T_marker = pose(facing_camera(rng.uniform(-20, 20), rng.uniform(-20, 20), 0), left_p)
        for side, cam, T in (("left", rig.left, np.eye(4)), ("right", rig.right, rig.right_T_left)):
            img = render_marker(cam, T @ left_T_marker, rng, marker_id=3, marker_length_m=0.04)
            cv2.imwrite(str(tmp_path / side / f"pose{i}.png"), img)
        base_p = transform_points(base_T_cam, left_p)[0]
        rows.append(f"pose{i}," + ",".join(f"{v:.6f}" for v in base_p))
    (tmp_path / "targets.csv").write_text("\n".join(rows) + "\n")
    rig.save(tmp_path / "stereo.yaml")
    code, stdout, stderr = run_cli(
        "register",
        "--rig",
        str(tmp_path / "stereo.yaml"),
        "--left",
        str(tmp_path / "left"),
        "--right",
        str(tmp_path / "right"),
        "--targets",
        str(tmp_path / "targets.csv"),
        "--marker-id",
        "3",
        "--out",
        str(tmp_path / "out"),
        "--json",
    )
    assert code == 0, stderr
    summary = json.loads(stdout)
    assert summary["points"] == 6 and summary["skipped"] == []
    assert summary["rms_m"] < 0.002
    fitted = load_base_T_cam(tmp_path / "out" / "base_T_cam.yaml")
    np.testing.assert_allclose(fitted[:3, 3], base_T_cam[:3, 3], atol=0.004)
    q_err = quaternion_from_matrix(fitted[:3, :3] @ cam_T_base[:3, :3])
    assert np.degrees(2 * np.arccos(min(1.0, q_err[0]))) < 1.0


def test_cli_register_needs_inputs(tmp_path: Path, run_cli: Any) -> None:
    code, _, stderr = run_cli("register", "--out", str(tmp_path))
    assert code == 2 and "give --points CSV" in stderr
    (tmp_path / "p.csv").write_text("name,cam_x,cam_y\n")
    code, _, stderr = run_cli(
        "register", "--points", str(tmp_path / "p.csv"), "--out", str(tmp_path)
    )
    assert code == 2 and "missing column(s) cam_z" in stderr
