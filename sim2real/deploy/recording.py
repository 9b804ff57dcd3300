"""``sim2real deploy --record-dataset DIR``: the deploy loop's periods as a LeRobot dataset.

The same writer as ``evaluate --record-dataset`` (``sim2real.datasets.lerobot``), fed from the
loop's own log: joint readings (``observation.state``), the normalised action, the tool and each
tracked object's estimate, and, where the backend has cameras (mock, real), both cameras as
videos (downscaled as the evaluation recorder does). One dataset episode per deploy episode, with
the task's string and its judged success; written atomically when the run ends.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from hardware.spec import ArmSpec
from sim2real.deploy.policy_io import PolicyIO

CAMERAS = ("cam_left", "cam_right")
IMAGE_HW = (240, 320)


class DeployRecorder:
    """Collects each period's frames and writes an episode when the loop finishes one."""

    def __init__(
        self, root: Path, spec: ArmSpec, io: PolicyIO, fps: float, cameras: bool,
        overwrite: bool = False,
    ) -> None:  # fmt: skip
        from sim2real.datasets.lerobot import (
            TASK_TEXT,
            DatasetSchema,
            LeRobotWriter,
            arm_features,
            camera_key,
        )

        self.io = io
        self.objects = io.contract.objects
        actions = list(spec.joint_names) + (["gripper"] if io.decoder.use_gripper else [])
        schema = DatasetSchema(
            fps=round(fps),
            features=arm_features(spec.actuator_names, actions, ["tool", *self.objects]),
            cameras=tuple(camera_key(c) for c in CAMERAS) if cameras else (),
            image_hw=IMAGE_HW,
        )
        self._camera_keys = schema.cameras
        self.task_text = TASK_TEXT.get(io.task, io.task)
        self.writer = LeRobotWriter(root, schema, overwrite)
        self._images: list[tuple[np.ndarray, np.ndarray]] = []

    def on_period(self, frames: tuple[np.ndarray, np.ndarray] | None) -> None:
        """The newest camera pair of this period (BGR), downscaled to RGB."""
        if not self._camera_keys:
            return
        import cv2

        h, w = IMAGE_HW
        if frames is None:
            blank = np.zeros((h, w, 3), np.uint8)
            pair = self._images[-1] if self._images else (blank, blank)
        else:
            pair = tuple(  # type: ignore[assignment]
                cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA)[:, :, ::-1].copy()
                for f in frames
            )
        self._images.append(pair)

    def on_episode(self, episode: int, success: bool, rows: dict[str, list[Any]]) -> None:
        from sim2real.datasets.lerobot import arm_frames

        idx = [i for i, e in enumerate(rows["episode"]) if e == episode]

        def column(key: str) -> np.ndarray:
            return np.asarray(
                [np.full(3, np.nan) if rows[key][i] is None else rows[key][i] for i in idx],
                dtype=float,
            )

        estimates = {"tool": column("ee_est_m")}
        estimates.update({name: column(f"{name}_est_m") for name in self.objects})
        frames = arm_frames(
            column("joints_rad").astype(np.float32),
            np.asarray([rows["action"][i] for i in idx], dtype=np.float32),
            {k: v.astype(np.float32) for k, v in estimates.items()},
        )
        images = None
        if self._camera_keys:
            shots = self._images[-len(idx) :]
            images = {
                key: np.stack([pair[side] for pair in shots])
                for side, key in enumerate(self._camera_keys)
            }
        self.writer.add_episode(frames, self.task_text, success, images)
        self._images.clear()

    def close(self) -> Path:
        return self.writer.close()

    def abort(self) -> None:
        self.writer.abort()
