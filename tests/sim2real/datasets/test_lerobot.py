"""The LeRobot v3.0 writer: layout and metadata, frame/video alignment, atomic writes, errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sim2real.datasets import (
    DatasetError,
    DatasetSchema,
    Feature,
    LeRobotDataset,
    LeRobotWriter,
    arm_features,
    arm_frames,
    camera_key,
    split_episodes,
)

HW = (48, 64)
CAMS = (camera_key("cam_left"), camera_key("cam_right"))


def _schema(cameras: tuple[str, ...] = CAMS) -> DatasetSchema:
    feats = arm_features(
        ["base_yaw", "shoulder", "elbow", "gripper"],
        ["base_yaw", "shoulder", "elbow", "gripper"],
        ["tool", "goal", "cube"],
        {"next.success": Feature((1,), "bool")},
    )
    return DatasetSchema(fps=20, features=feats, cameras=cameras, image_hw=HW)


def _episode(rng: np.random.Generator, n: int, first_shade: int) -> tuple[dict, dict]:
    """Per-step arrays, and frames whose brightness encodes (camera, step) for alignment checks."""
    frames = arm_frames(
        rng.normal(size=(n, 4)),
        rng.uniform(-1, 1, size=(n, 4)),
        {k: rng.normal(size=(n, 3)) for k in ("tool", "goal", "cube")},
        {"next.success": np.arange(n) == n - 1},
    )
    shades = first_shade + 4 * np.arange(n)
    images = {
        cam: np.broadcast_to(
            (shades + 100 * c)[:, None, None, None].astype(np.uint8), (n, *HW, 3)
        ).copy()
        for c, cam in enumerate(CAMS)
    }
    return frames, images


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict]]:
    root = tmp_path_factory.mktemp("lerobot") / "pick"
    rng = np.random.default_rng(0)
    episodes = []
    with LeRobotWriter(root, _schema()) as w:
        for ep, n in enumerate((7, 12, 9)):
            frames, images = _episode(rng, n, first_shade=10 * ep)
            w.add_episode(frames, "pick up the cube", success=ep != 1, images=images)
            episodes.append({"frames": frames, "images": images})
    return root, episodes


def test_layout_and_info_are_lerobot_v30(written: tuple[Path, list[dict]]) -> None:
    root, _ = written
    for rel in (
        "meta/info.json",
        "meta/stats.json",
        "meta/tasks.parquet",
        "meta/episodes/chunk-000/file-000.parquet",
        "data/chunk-000/file-000.parquet",
        f"videos/{CAMS[0]}/chunk-000/file-000.mp4",
        f"videos/{CAMS[1]}/chunk-000/file-000.mp4",
    ):
        assert (root / rel).is_file(), rel
    info = json.loads((root / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0"
    assert (info["total_episodes"], info["total_frames"], info["fps"]) == (3, 28, 20)
    assert info["features"]["observation.state"]["names"][-1] == "gripper"
    assert info["features"][CAMS[0]]["shape"] == [48, 64, 3]
    assert info["features"][CAMS[0]]["dtype"] == "video"
    for key in ("timestamp", "frame_index", "episode_index", "index", "task_index"):
        assert info["features"][key]["shape"] == [1]


def test_parquet_rows_index_and_task_lookup(written: tuple[Path, list[dict]]) -> None:
    import pyarrow.parquet as pq

    root, episodes = written
    data = pq.read_table(root / "data/chunk-000/file-000.parquet")
    assert data.num_rows == 28
    assert data.column("index").to_pylist() == list(range(28))
    state = np.array(data.column("observation.state").to_pylist(), dtype=np.float32)
    np.testing.assert_allclose(state[:7], episodes[0]["frames"]["observation.state"], rtol=1e-6)
    eps = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [e["dataset_from_index"] for e in eps] == [0, 7, 19]
    assert [e["success"] for e in eps] == [True, False, True]
    assert eps[1][f"videos/{CAMS[0]}/from_timestamp"] == pytest.approx(7 / 20)
    tasks = pq.read_table(root / "meta/tasks.parquet")
    pandas_meta = json.loads(tasks.schema.metadata[b"pandas"])
    assert pandas_meta["index_columns"] == ["task"]  # LeRobot looks tasks up by this index
    assert tasks.column("task").to_pylist() == ["pick up the cube"]


def test_read_back_frames_and_every_video_frame_in_place(written: tuple[Path, list[dict]]) -> None:
    root, episodes = written
    ds = LeRobotDataset.open(root)
    assert ds.summary()["episodes"] == 3 and ds.total_frames == 28
    assert ds.summary()["success_rate"] == pytest.approx(2 / 3)
    got = ds.episode_frames(1)
    np.testing.assert_allclose(got["action"], episodes[1]["frames"]["action"], rtol=1e-6)
    assert got["next.success"].tolist() == [False] * 11 + [True]
    for cam in CAMS:
        decoded = np.stack(list(ds.video_frames(1, cam)))
        want = episodes[1]["images"][cam]
        assert decoded.shape == want.shape
        # H.264 is lossy; each frame's shade is 4 apart from its neighbours', so a frame taken
        # from the wrong episode or step is off by >= 4.
        err = np.abs(decoded.astype(float).mean((1, 2, 3)) - want.astype(float).mean((1, 2, 3)))
        assert err.max() < 2.0


def test_stats_skip_nan_estimates(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    frames, _ = _episode(rng, 5, 0)
    frames["observation.cube_pos"][2] = np.nan  # the cube was not seen at that step
    with LeRobotWriter(tmp_path / "ds", _schema(cameras=())) as w:
        w.add_episode(frames, "pick up the cube", success=False)
    stats = json.loads((tmp_path / "ds/meta/stats.json").read_text())
    cube = np.array(frames["observation.cube_pos"], dtype=np.float32)  # as stored
    np.testing.assert_allclose(
        stats["observation.cube_pos"]["mean"], np.nanmean(cube, 0), rtol=1e-6
    )
    assert stats["observation.cube_pos"]["count"] == [5]


def test_an_error_leaves_no_dataset_and_no_temp_folder(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    frames, images = _episode(rng, 4, 0)
    with pytest.raises(RuntimeError), LeRobotWriter(tmp_path / "ds", _schema()) as w:
        w.add_episode(frames, "pick up the cube", True, images)
        raise RuntimeError("the loop failed")
    assert list(tmp_path.iterdir()) == []


def test_existing_folder_is_kept_unless_overwrite(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    root = tmp_path / "ds"
    root.mkdir()
    (root / "keep.txt").write_text("mine")
    with pytest.raises(DatasetError, match="exists"):
        LeRobotWriter(root, _schema(cameras=()))
    frames, _ = _episode(rng, 3, 0)
    with LeRobotWriter(root, _schema(cameras=()), overwrite=True) as w:
        w.add_episode(frames, "pick up the cube", True)
    assert not (root / "keep.txt").exists() and (root / "meta/info.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda f, i: f.pop("action"), "missing \\['action'\\]"),
        (lambda f, i: f.update(action=f["action"][:-1]), "lengths"),
        (lambda f, i: f.update(action=f["action"][:, :3]), "action: shape"),
        (lambda f, i: i.update({CAMS[0]: i[CAMS[0]][:, :10]}), "cam_left: frames"),
    ],
)
def test_bad_episodes_are_rejected_by_name(tmp_path: Path, change: object, message: str) -> None:
    rng = np.random.default_rng(4)
    frames, images = _episode(rng, 4, 0)
    change(frames, images)  # type: ignore[operator]
    w = LeRobotWriter(tmp_path / "ds", _schema())
    with pytest.raises(DatasetError, match=message):
        w.add_episode(frames, "pick up the cube", True, images)
    w.abort()
    assert list(tmp_path.iterdir()) == []


def test_schema_rejects_reserved_and_odd_sizes() -> None:
    with pytest.raises(Exception, match="index"):
        DatasetSchema(20, {"index": Feature((1,), "int64")})
    with pytest.raises(Exception, match="even"):
        DatasetSchema(20, {}, cameras=CAMS, image_hw=(47, 64))


def test_a_flat_loop_log_becomes_episodes_in_a_dataset(tmp_path: Path) -> None:
    """The deploy loop's log shape: one row per period, an episode column, per-run extras."""
    rng = np.random.default_rng(5)
    episode = np.repeat([0.0, 1.0, 2.0], [4, 6, 3])  # npz logs store it as float
    log = {
        "episode": episode,
        "joints_rad": rng.normal(size=(13, 4)),
        "action": rng.uniform(-1, 1, size=(13, 4)),
        "ee_est_m": rng.normal(size=(13, 3)),
        "goal_est_m": rng.normal(size=(13, 3)),
        "cube_est_m": rng.normal(size=(13, 3)),
        "spec_fingerprint": np.array([1.0, 2.0]),  # not per step: left out
    }
    parts = split_episodes(log)
    assert [len(p["action"]) for p in parts] == [4, 6, 3]
    assert all("spec_fingerprint" not in p for p in parts)
    with LeRobotWriter(tmp_path / "ds", _schema(cameras=())) as w:
        for p, ok in zip(parts, (True, False, True), strict=True):
            est = {"tool": p["ee_est_m"], "goal": p["goal_est_m"], "cube": p["cube_est_m"]}
            extras = {"next.success": np.arange(len(p["action"])) == len(p["action"]) - 1}
            w.add_episode(arm_frames(p["joints_rad"], p["action"], est, extras), "pick", ok)
    ds = LeRobotDataset.open(tmp_path / "ds")
    assert [e.length for e in ds.episodes] == [4, 6, 3]
    np.testing.assert_allclose(
        ds.episode_frames(1)["observation.state"], log["joints_rad"][4:10], rtol=1e-6
    )
    with pytest.raises(DatasetError, match="no 'episode' column"):
        split_episodes({"action": log["action"]})
