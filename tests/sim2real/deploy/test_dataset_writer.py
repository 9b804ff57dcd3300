"""The deploy dataset is written off the control thread: a disk that stalls never holds a
period (nor the hold between episodes, a real arm's 0.25 s host watchdog), and whatever ends the
run, the finished episodes are drained and moved into place whole.

Judged on SimArm's lockstep clock and on events, never on a rate: the slow sink blocks on an
event the test releases only after the run, so a recorder that wrote on the control thread
would stall the run until the sink's generous time-out and the test would fail."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from timescale import scaled  # type: ignore[import-not-found]

from hardware.spec import ArmSpec
from sim2real.datasets.lerobot import LeRobotDataset, LeRobotWriter
from sim2real.deploy.connection import BACKENDS
from sim2real.deploy.loop import DeployLoop, LoopConfig
from sim2real.deploy.policy_io import PolicyIO
from sim2real.deploy.recording import DeployRecorder, RecordingError, dataset_schema
from sim2real.deploy.runner import run_policy

from .conftest import FAST, LOCKSTEP, ik_policy  # type: ignore[import-not-found]


class StalledDisk:
    """A real ``LeRobotWriter`` behind a disk that stalls: every episode waits for ``release``
    (or a time-out far beyond any run, so a broken recorder fails the test instead of hanging)."""

    def __init__(self, writer: LeRobotWriter) -> None:
        self.writer = writer
        self.release = threading.Event()
        self.entered = threading.Event()
        self.written_before_release = 0

    @property
    def episodes(self) -> int:
        return self.writer.episodes

    def add_episode(
        self,
        frames: Mapping[str, np.ndarray],
        task: str,
        success: bool,
        images: Mapping[str, np.ndarray] | None = None,
    ) -> int:
        self.entered.set()
        if not self.release.wait(scaled(120.0)):
            self.written_before_release += 1
        return self.writer.add_episode(frames, task, success, images)

    def close(self) -> Path:
        return self.writer.close()

    def abort(self) -> None:
        self.writer.abort()


def _stalled_recorder(root: Path, spec: ArmSpec, io: PolicyIO) -> tuple[Any, StalledDisk]:
    disk = StalledDisk(LeRobotWriter(root, dataset_schema(spec, io, FAST["rate_hz"], False)))
    return DeployRecorder(root, spec, io, FAST["rate_hz"], cameras=False, sink=disk), disk


def test_a_stalled_disk_never_holds_the_loop_and_the_dataset_is_whole_after(
    spec: ArmSpec, reach_io: PolicyIO, tmp_path: Path
) -> None:
    root, log = tmp_path / "ds", tmp_path / "run.npz"
    recorder, disk = _stalled_recorder(root, spec, reach_io)
    with contextlib.ExitStack() as stack:
        arm, perception, world = BACKENDS["sim"](spec, reach_io, LOCKSTEP, stack)
        loop = DeployLoop(
            arm, perception, world, ik_policy(spec, reach_io.builder, reach_io.decoder),
            reach_io, LoopConfig(episodes=3, **FAST), log_path=log,
            on_episode=recorder.on_episode,
        )  # fmt: skip
        result = loop.run()
    # every episode ran, parked and logged while the disk had written nothing
    assert len(result.episodes) == 3 and result.stopped_early is None
    assert disk.entered.is_set() and disk.episodes == 0 and recorder.backlog >= 1
    assert not root.exists()  # nothing in place before the run's data is whole
    disk.release.set()
    assert recorder.close() == root
    assert disk.written_before_release == 0
    ds = LeRobotDataset.open(root)
    data = np.load(log)
    assert len(ds.episodes) == 3 and ds.total_frames == data["obs"].shape[0]
    for ep in range(3):
        rows = data["episode"] == ep
        got = ds.episode_frames(ep)
        np.testing.assert_allclose(got["observation.state"], data["joints_rad"][rows], atol=1e-6)
        np.testing.assert_allclose(got["action"], data["action"][rows], atol=1e-6)
    assert [e.success for e in ds.episodes] == [e.success for e in result.episodes]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".ds.")]  # no temp left


def test_a_fault_mid_run_keeps_the_finished_episodes_whole(
    spec: ArmSpec, reach_io: PolicyIO, tmp_path: Path
) -> None:
    """The policy fails in the third episode: the run stops safely, the two finished episodes
    are drained to disk and moved into place; the one in flight is not half-written."""
    root = tmp_path / "ds"
    ik = ik_policy(spec, reach_io.builder, reach_io.decoder)
    steps = {"n": 0}

    def fails_in_the_third_episode(obs: np.ndarray) -> np.ndarray:
        steps["n"] += 1
        if steps["n"] == 2 * reach_io.episode_steps + 5:
            raise RuntimeError("policy server went away")
        return ik(obs)

    with pytest.raises(RuntimeError, match="policy server went away"):
        run_policy(
            fails_in_the_third_episode, reach_io, spec, LOCKSTEP,
            LoopConfig(episodes=3, **FAST), dataset_path=root,
        )  # fmt: skip
    ds = LeRobotDataset.open(root)
    assert len(ds.episodes) == 2 and ds.total_frames == 2 * reach_io.episode_steps
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".ds.")]


def test_a_writer_that_fails_leaves_no_dataset_and_says_why_in_one_line(
    spec: ArmSpec, reach_io: PolicyIO, tmp_path: Path
) -> None:
    root = tmp_path / "ds"
    recorder = DeployRecorder(root, spec, reach_io, FAST["rate_hz"], cameras=False)
    bad_rows = {"episode": [0, 0], "joints_rad": [np.zeros(3), np.zeros(3)],
                "action": [np.zeros(2)] * 2, "ee_est_m": [None, None],
                "target_est_m": [None, None]}  # fmt: skip  # actions of the wrong width
    recorder.on_episode(0, True, bad_rows)
    with pytest.raises(RecordingError, match="the dataset was not written: ") as err:
        recorder.close()
    assert "\n" not in str(err.value)
    assert not root.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".ds.")]
