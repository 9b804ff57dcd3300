"""``record_dataset``: evaluation rollouts become a LeRobot dataset, frame t = (obs_t, action_t)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sim2real.datasets import LeRobotDataset
from sim2real.errors import ConfigError
from sim2real.evaluate.dataset import parse_image_size, record_dataset


def test_frames_pair_each_observation_with_the_action_taken_on_it(
    ik_target: Any, tmp_path: Path
) -> None:
    seeds = ik_target.held_out_seeds(2)
    out = tmp_path / "reach"
    path, result, frames = record_dataset(
        ik_target, out, ik_target.train_dr, seeds, image_hw=(48, 64)
    )
    ds = LeRobotDataset.open(path)
    assert frames == ds.total_frames == sum(e.length for e in result.episodes)
    assert [e.success for e in ds.episodes] == [e.success for e in result.episodes]
    assert ds.episodes[0].task == "move the tool tip to the target"
    assert ds.cameras == ["observation.images.cam_left", "observation.images.cam_right"]
    for ep in range(2):
        f = ds.episode_frames(ep)
        # The IK policy acts on (joint_pos, goal_pos): recomputing its action from the recorded
        # state and goal estimate must give the recorded action, step for step.
        obs = np.zeros((len(f["action"]), 24), dtype=np.float32)
        obs[:, 0:3], obs[:, 6:9] = f["observation.state"], f["observation.goal_pos"]
        np.testing.assert_allclose(ik_target.policy(obs), f["action"], atol=1e-6)
        assert f["next.done"].tolist() == [False] * (len(f["action"]) - 1) + [True]
        assert bool(f["next.success"][-1]) == result.episodes[ep].success
        np.testing.assert_allclose(f["next.reward"].sum(), result.episodes[ep].ret, rtol=1e-5)
        for cam in ds.cameras:
            shots = list(ds.video_frames(ep, cam))
            assert len(shots) == len(f["action"]) and shots[0].shape == (48, 64, 3)
    # The tool starts away from the target and ends at it (the IK policy succeeds).
    tool, goal = f["observation.tool_pos"], f["observation.goal_pos"]
    assert np.linalg.norm(tool[-1] - goal[-1]) < np.linalg.norm(tool[0] - goal[0])


def test_without_cameras(ik_target: Any, tmp_path: Path) -> None:
    seeds = ik_target.held_out_seeds(1)
    path, _, frames = record_dataset(ik_target, tmp_path / "d", ik_target.train_dr, seeds, None)
    ds = LeRobotDataset.open(path)
    assert ds.cameras == [] and ds.total_frames == frames > 0
    assert not (path / "videos").exists()


@pytest.mark.parametrize("text", ["320", "320x", "0x0", "321x240", "axb"])
def test_bad_image_size_is_one_clear_error(text: str) -> None:
    with pytest.raises(ConfigError, match="image size"):
        parse_image_size(text)
    assert parse_image_size("320x240") == (240, 320)
