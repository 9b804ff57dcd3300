"""CI's end-to-end check: the same trained reach policy in simulation and through the whole mock
chain (emulator on a pty, rendered cameras, ArUco, triangulation, Kalman), via the CLI.

The policy is the shipped ``reach-ppo`` (``sim2real policies``): nothing is trained or
downloaded. The transfer check runs ten mock episodes on the wall clock (about a minute on a
loaded 2-core machine), so it is marked slow: CI runs it after the main suite (``.ci/run``), and
the default run keeps the chain's shorter checks (test_loop.py, test_recording.py).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from timescale import scaled  # type: ignore[import-not-found]

MOCK_EPISODES = 10
POLICY = "reach-ppo"  # shipped: a trained reach policy, measured (its card), no training here


def _cli(*args: str, timeout: float = 600) -> dict:
    res = subprocess.run(
        [sys.executable, "-m", "sim2real", *args], capture_output=True, text=True,
        timeout=scaled(timeout),
    )  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


@pytest.mark.slow
@pytest.mark.realtime
def test_mock_deployment_keeps_the_sim_success_of_the_same_policy(tmp_path: Path) -> None:
    sim = _cli("evaluate", POLICY, "--episodes", "40", "--dr", "none", "--json")
    p_sim = sim["success_rate"]
    assert p_sim >= 0.5, f"the shipped policy is too weak to judge transfer: {p_sim}"
    log = tmp_path / "mock.npz"
    # --watchdog-s: under pytest -n 2 a period may run long; this test judges the chain, not the
    # timing (bench/deploy_mock.py holds the 20 Hz and watchdog targets).
    mock = _cli(
        "deploy", POLICY, "--backend", "mock", "--episodes", str(MOCK_EPISODES),
        "--log", str(log), "--json", "--watchdog-s", str(scaled(10)),
        "--start-timeout", str(scaled(60)),
    )  # fmt: skip
    assert mock["episodes"] == MOCK_EPISODES and mock["stopped_early"] is None
    # Threshold derived from the sim success: 90 % of it, less two binomial standard errors of a
    # 10-episode estimate (so a sound chain fails this by chance < 3 % of the time).
    threshold = 0.9 * p_sim - 2 * math.sqrt(p_sim * (1 - p_sim) / MOCK_EPISODES)
    assert mock["success_rate"] >= threshold, (mock, p_sim, threshold)
    assert mock["task"] == "reach" and mock["watchdog_trips"] == 0
    assert set(mock["sections_ms"]) == {"read", "perceive", "infer", "command"}
    assert log.is_file()


def test_deploy_refuses_a_run_for_a_different_arm_spec(tmp_path: Path) -> None:
    from hardware.spec import DEFAULT_SPEC_PATH

    other = tmp_path / "longer_arm.yaml"
    other.write_text(DEFAULT_SPEC_PATH.read_text().replace("forearm_m: 0.12", "forearm_m: 0.14"))
    res = subprocess.run(
        [sys.executable, "-m", "sim2real", "deploy", POLICY, "--backend", "sim",
         "--spec", str(other), "--episodes", "1"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2
    assert "was trained for arm spec" in res.stderr and res.stderr.count("\n") == 1


@pytest.mark.realtime  # starts the mock's processes, then refuses before the arm moves
def test_a_calibration_for_another_resolution_is_refused_before_moving(tmp_path: Path) -> None:
    import numpy as np

    from calibration.camera import CameraModel
    from calibration.triangulate import StereoRig

    K = np.array([[900.0, 0, 639.5], [0, 900.0, 359.5], [0, 0, 1]])
    cams = [CameraModel(K, np.zeros(5), (1280, 720), name=n) for n in ("left", "right")]
    path = tmp_path / "stereo_720p.yaml"
    StereoRig(cams[0], cams[1], np.eye(3), np.array([-0.1, 0.0, 0.0])).save(path)
    res = subprocess.run(
        [sys.executable, "-m", "sim2real", "deploy", POLICY, "--backend", "mock",
         "--calibration", str(path), "--episodes", "1"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2, res.stderr
    assert "delivers 640x480 frames but the stereo calibration is for 1280x720" in res.stderr
