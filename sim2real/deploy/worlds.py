"""Worlds: who places the target each episode and who knows the truth.

``SimWorld`` and ``MockWorld`` know the true tool position (MuJoCo, or the emulator's true servo
angles through the spec's FK), so deploy reports real success rates; on a real arm success is
judged from the camera estimates.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from hardware.errors import HardwareError
from hardware.spec import ArmSpec
from sim2real.deploy.loop import Percept
from sim2real.deploy.perception import StereoFrameSource
from sim2real.deploy.virtual_cameras import VirtualStereoCameras
from sim2real.envs.workspace import sample_reachable

TargetSampler = Callable[[np.random.Generator], np.ndarray]


class _TargetWorld:
    def __init__(self, spec: ArmSpec, threshold_m: float, sampler: TargetSampler | None) -> None:
        self.spec = spec
        self.threshold_m = threshold_m
        self._sample = sampler or (lambda rng: sample_reachable(spec, rng))
        self.target_m = np.zeros(3)

    def new_episode(self, rng: np.random.Generator) -> None:
        self.target_m = np.asarray(self._sample(rng), dtype=float)

    def true_tool_m(self) -> np.ndarray:
        raise NotImplementedError

    def success(self, percept: Percept) -> tuple[bool, float]:
        d = float(np.linalg.norm(self.true_tool_m() - self.target_m))
        return d < self.threshold_m, d


class SimWorld(_TargetWorld):
    """Truth from the SimArm's MuJoCo state; the target is drawn in its scene."""

    def __init__(
        self,
        spec: ArmSpec,
        tool: Callable[[], np.ndarray],
        place_target: Callable[[np.ndarray], None],
        threshold_m: float = 0.01,
        sampler: TargetSampler | None = None,
    ) -> None:
        super().__init__(spec, threshold_m, sampler)
        self._tool, self._place = tool, place_target

    def new_episode(self, rng: np.random.Generator) -> None:
        super().new_episode(rng)
        self._place(self.target_m)

    def true_tool_m(self) -> np.ndarray:
        return np.asarray(self._tool(), dtype=float)


class MockWorld(_TargetWorld, StereoFrameSource):
    """The emulator's true servo angles pose a rendered scene; the cameras see it."""

    def __init__(
        self,
        spec: ArmSpec,
        true_positions: Callable[[], np.ndarray],
        cameras: VirtualStereoCameras,
        threshold_m: float = 0.01,
        sampler: TargetSampler | None = None,
        camera_fails_after_frames: int | None = None,
    ) -> None:
        super().__init__(spec, threshold_m, sampler)
        self._true_positions = true_positions
        self.cameras = cameras
        self.frames_rendered = 0
        self._fail_after = camera_fails_after_frames  # fault injection: a camera that dies

    def true_tool_m(self) -> np.ndarray:
        return self.spec.forward_kinematics(self._true_positions()[: self.spec.n_joints])

    def read_pair(self) -> tuple[np.ndarray, np.ndarray, float]:
        if self._fail_after is not None and self.frames_rendered >= self._fail_after:
            raise HardwareError(
                f"camera stopped delivering frames after {self.frames_rendered} frames"
            )
        self.cameras.pose(self._true_positions(), self.target_m)
        frames = self.cameras.read()
        self.frames_rendered += 1
        return frames.left_bgr, frames.right_bgr, frames.timestamp_s

    def close(self) -> None:
        self.cameras.close()
