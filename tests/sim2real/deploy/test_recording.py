"""``deploy --record-dataset``: the loop's periods become a LeRobot dataset, cameras included."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from timescale import scaled  # type: ignore[import-not-found]

from sim2real.cli.main import main
from sim2real.datasets.lerobot import LeRobotDataset


# slow (CI runs it after the main suite): the viewer's test records a mock deploy's dataset with
# both cameras in the fast suite (tests/sim2real/view/conftest.py), the writer's layout is judged
# in tests/sim2real/datasets; this one checks two episodes' indices, fps and success flags
@pytest.mark.realtime
@pytest.mark.slow
def test_a_mock_deployment_records_a_lerobot_dataset_with_both_cameras(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = tmp_path / "ds"
    args = [
        "deploy", "reach-ppo", "--backend", "mock", "--episodes", "2", "--json",
        "--record-dataset", str(root), "--log", str(tmp_path / "log.npz"),
        "--watchdog-s", str(scaled(10)), "--start-timeout", str(scaled(60)),
        "--camera-fps", "20",  # a frame a period (conftest's MOCK): less CPU, the same frames kept
    ]  # fmt: skip
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out.splitlines()[-1])
    ds = LeRobotDataset.open(root)
    info = ds.summary()
    assert info["episodes"] == 2 and ds.total_frames == 100 and ds.fps == 20
    assert len(ds.cameras) == 2
    assert {"observation.state", "action", "observation.tool_pos", "observation.target_pos"} <= set(
        ds.features
    )
    ep = ds.episode_frames(0)
    log = np.load(tmp_path / "log.npz")
    np.testing.assert_allclose(ep["observation.state"], log["joints_rad"][:50], atol=1e-6)
    frames = list(ds.video_frames(1, ds.cameras[0]))
    assert len(frames) == 50 and frames[0].shape == (240, 320, 3) and frames[0].std() > 5
    successes = [e.success for e in ds.episodes] if hasattr(ds, "episodes") else None
    if successes is not None:
        assert sum(successes) == round(summary["success_rate"] * 2)


def test_a_dataset_folder_that_exists_is_refused_before_moving(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "ds").mkdir()
    args = ["deploy", "reach-ppo", "--backend", "sim", "--record-dataset", str(tmp_path / "ds")]
    assert main(args) == 2
    assert "exists; choose a new one" in capsys.readouterr().err
