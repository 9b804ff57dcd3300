"""``sim2real deploy --record-dataset DIR``: the deploy loop's periods as a LeRobot dataset.

The same writer as ``evaluate --record-dataset`` (``sim2real.datasets.lerobot``), fed from the
loop's own log: joint readings (``observation.state``), the normalised action, the tool and each
tracked object's estimate, and, where the backend has cameras (mock, real), both cameras as
videos (downscaled as the evaluation recorder does). One dataset episode per deploy episode, with
the task's string and its judged success.

Nothing here runs on the control thread but a queue put: downscaling, encoding and the disk are
a writer thread's (``DatasetWriterThread``), so a slow disk or encoder never stretches a control
period, nor the hold between episodes (a real arm's 0.25 s host watchdog). When the run ends,
well or on a fault, the queue is drained and the finished episodes are moved into place at once
(``LeRobotWriter``'s temporary folder and rename): never half a dataset, never half an episode.
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from hardware.spec import ArmSpec
from sim2real.deploy.policy_io import PolicyIO
from sim2real.errors import Sim2RealError

log = logging.getLogger(__name__)

CAMERAS = ("cam_left", "cam_right")
IMAGE_HW = (240, 320)
WRITER_NICE = 10  # below the control loop and perception: the disk waits, the arm does not
_KEYS = ("episode", "joints_rad", "action", "ee_est_m")


class DatasetSink(Protocol):
    """Where finished episodes go (``LeRobotWriter``; a test may wrap it in a slow one)."""

    @property
    def episodes(self) -> int: ...

    def add_episode(
        self,
        frames: Mapping[str, np.ndarray],
        task: str,
        success: bool,
        images: Mapping[str, np.ndarray] | None = None,
    ) -> int: ...

    def close(self) -> Path: ...

    def abort(self) -> None: ...


def dataset_schema(spec: ArmSpec, io: PolicyIO, fps: float, cameras: bool) -> Any:
    """The deploy dataset's ``DatasetSchema``: readings, actions, the tool and each object's
    estimate, and both cameras where the backend has them."""
    from sim2real.datasets.lerobot import DatasetSchema, arm_features, camera_key

    actions = list(spec.joint_names) + (["gripper"] if io.decoder.use_gripper else [])
    return DatasetSchema(
        fps=round(fps),
        features=arm_features(spec.actuator_names, actions, ["tool", *io.contract.objects]),
        cameras=tuple(camera_key(c) for c in CAMERAS) if cameras else (),
        image_hw=IMAGE_HW,
    )


class RecordingError(Sim2RealError):
    """The dataset writer failed (a full disk, a dead encoder); the run's arm is not affected."""


class DeployRecorder:
    """Takes each period's frames and each finished episode from the control thread (a queue
    put each) and hands them to a writer thread that builds the dataset."""

    def __init__(
        self, root: Path, spec: ArmSpec, io: PolicyIO, fps: float, cameras: bool,
        overwrite: bool = False, sink: DatasetSink | None = None,
    ) -> None:  # fmt: skip
        from sim2real.datasets.lerobot import TASK_TEXT, LeRobotWriter

        self.io = io
        self.objects = io.contract.objects
        schema = dataset_schema(spec, io, fps, cameras)
        self._camera_keys = schema.cameras
        self.task_text = TASK_TEXT.get(io.task, io.task)
        self.writer: DatasetSink = sink or LeRobotWriter(root, schema, overwrite)
        self._keys = (*_KEYS, *(f"{name}_est_m" for name in self.objects))
        self._row_start = 0  # the first log row of the episode in flight
        self._thread = DatasetWriterThread(self)
        self._thread.start()

    # ---- the control thread's side: one queue put each ----------------------------------------
    def on_period(self, frames: tuple[np.ndarray, np.ndarray] | None) -> None:
        """The newest camera pair of this period (BGR), downscaled to RGB here (a fraction of a
        millisecond, after the command is sent: the queue holds small frames however long the
        disk makes it wait)."""
        if self._camera_keys:
            self._thread.put(("frames", self._downscale(frames)))

    def on_episode(self, episode: int, success: bool, rows: Mapping[str, list[Any]]) -> None:
        """An episode ended: its log rows (a copy of the slices, the log grows on) are queued."""
        self._thread.check()
        start, end = self._row_start, len(rows["episode"])
        mine = [i for i in range(start, end) if rows["episode"][i] == episode]
        part = {k: [rows[k][i] for i in mine] for k in self._keys if k in rows}
        self._row_start = end
        self._thread.put(("episode", episode, success, part))

    @property
    def backlog(self) -> int:
        """Items queued for the writer thread and not yet written."""
        return self._thread.backlog

    # ---- the end of the run -------------------------------------------------------------------
    def close(self) -> Path | None:
        """Drain the queue, then move the dataset into place (None: no episode finished, so
        nothing is written). Raises ``RecordingError`` if the writer failed."""
        self._thread.stop()
        failed = self._thread.error
        if failed is not None:
            self.writer.abort()
            raise RecordingError(f"the dataset was not written: {_one_line(failed)}") from failed
        if self.writer.episodes == 0:
            log.warning("no episode finished: no dataset written")
            self.writer.abort()
            return None
        return self.writer.close()

    def finish_after_fault(self) -> Path | None:
        """After a fault or a Ctrl-C: the episodes that finished are kept (the one in flight
        never reached the queue); a failure here is logged, never raised over the fault."""
        try:
            path = self.close()
        except Exception as exc:
            log.error("dataset: %s", _one_line(exc))
            with contextlib.suppress(Exception):
                self.writer.abort()
            return None
        if path is not None:
            log.warning(
                "dataset: the %d finished episode(s) kept in %s", self.writer.episodes, path
            )
        return path

    def abort(self) -> None:
        """Drop everything (the writer thread stops first)."""
        self._thread.stop()
        self.writer.abort()

    def _downscale(self, frames: tuple[np.ndarray, np.ndarray] | None) -> Any:
        if frames is None:
            return None
        import cv2

        h, w = IMAGE_HW
        return tuple(
            cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA)[:, :, ::-1].copy() for f in frames
        )

    # ---- the writer thread's side -------------------------------------------------------------
    def _write_episode(
        self, success: bool, part: Mapping[str, list[Any]], images: list[Any]
    ) -> None:
        from sim2real.datasets.lerobot import arm_frames

        def column(key: str) -> np.ndarray:
            return np.asarray(
                [np.full(3, np.nan) if v is None else v for v in part[key]], dtype=float
            )

        estimates = {"tool": column("ee_est_m")}
        estimates.update({name: column(f"{name}_est_m") for name in self.objects})
        frames = arm_frames(
            column("joints_rad").astype(np.float32),
            np.asarray(part["action"], dtype=np.float32),
            {k: v.astype(np.float32) for k, v in estimates.items()},
        )
        shots = None
        if self._camera_keys:
            n = len(part["episode"])
            h, w = IMAGE_HW
            blank = np.zeros((h, w, 3), np.uint8)
            pairs: list[tuple[np.ndarray, np.ndarray]] = []
            for pair in images[-n:] if n else []:
                pairs.append(pair if pair is not None else (pairs[-1] if pairs else (blank, blank)))
            while len(pairs) < n:  # periods with no frame yet: blank, as before the first pair
                pairs.insert(0, (blank, blank))
            shots = {
                key: np.stack([p[side] for p in pairs])
                for side, key in enumerate(self._camera_keys)
            }
        self.writer.add_episode(frames, self.task_text, success, shots)


class DatasetWriterThread:
    """The recorder's worker: takes items off an unbounded queue (a put never blocks the
    control thread) and writes them in order; ``stop`` drains the queue first."""

    def __init__(self, recorder: DeployRecorder) -> None:
        self._recorder = recorder
        self._queue: queue.Queue[Any] = queue.Queue()
        self._thread = threading.Thread(target=self._work, name="dataset-writer", daemon=True)
        self.error: BaseException | None = None

    def start(self) -> None:
        self._thread.start()

    def put(self, item: Any) -> None:
        self._queue.put(item)

    @property
    def backlog(self) -> int:
        return self._queue.qsize()

    def check(self) -> None:
        """Raise the writer's failure on the control thread's next hand-over (one line)."""
        if self.error is not None:
            raise RecordingError(f"the dataset writer stopped: {_one_line(self.error)}")

    def stop(self) -> None:
        """Drain what is queued and stop (idempotent)."""
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()

    def _work(self) -> None:
        with contextlib.suppress(OSError, AttributeError):  # Linux: per-thread nice
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), WRITER_NICE)
        rec, images = self._recorder, []
        while True:
            item = self._queue.get()
            if item is None:
                return
            if self.error is not None:
                continue  # failed: drain and drop, so stop() never waits on a full queue
            try:
                if item[0] == "frames":
                    images.append(item[1])
                else:
                    _, _, success, part = item
                    rec._write_episode(success, part, images)
                    images = []
            except Exception as exc:
                log.error("dataset writer: %s", _one_line(exc))
                self.error = exc


def _one_line(exc: BaseException) -> str:
    return (str(exc).splitlines() or [type(exc).__name__])[0]
