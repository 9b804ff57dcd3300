"""``sim2real evaluate RUN --record-dataset DIR``: held-out rollouts saved as a LeRobot dataset.

Frame t holds what the policy saw and did at step t: the joint readings and the tool/goal/cube
estimates (slices of its observation, so the same noise, lag and Kalman smoothing as in
training), the action, both rig cameras rendered from the state it acted on, and what the step
earned (``next.reward``, ``next.success``, ``next.done``). Each episode carries its task string
and its success.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from sim2real.datasets import (
    TASK_TEXT,
    DatasetSchema,
    Feature,
    LeRobotWriter,
    arm_features,
    arm_frames,
    camera_key,
)
from sim2real.errors import ConfigError
from sim2real.evaluate.core import EvalTarget
from sim2real.evaluate.rollout import Episode, EvalResult, Transition, run_episodes
from sim2real.progress import progress_bar
from sim2real.randomization import DRConfig

# Observation fields recorded as named position estimates (base frame, m).
ESTIMATE_FIELDS: dict[str, str] = {"tool": "ee_pos", "goal": "goal_pos", "cube": "cube_pos"}
STEP_FEATURES: dict[str, Feature] = {
    "next.reward": Feature((1,), "float32"),
    "next.success": Feature((1,), "bool"),
    "next.done": Feature((1,), "bool"),
}
DEFAULT_IMAGE_HW: tuple[int, int] = (240, 320)


def parse_image_size(text: str) -> tuple[int, int]:
    """``"320x240"`` -> (height, width) = (240, 320)."""
    try:
        w_s, h_s = text.lower().split("x")
        w, h = int(w_s), int(h_s)
    except ValueError:
        raise ConfigError(f"image size {text!r}: give WIDTHxHEIGHT, e.g. 320x240") from None
    if not (16 <= w <= 1920 and 16 <= h <= 1080) or w % 2 or h % 2:
        raise ConfigError(f"image size {text!r}: even sides, 16x16 to 1920x1080")
    return h, w


@dataclass
class _EpisodeBuffer:
    steps: dict[str, list[Any]] = field(default_factory=dict)
    images: dict[str, list[np.ndarray]] = field(default_factory=dict)
    pending: dict[str, np.ndarray] = field(default_factory=dict)  # cameras at the current state

    def add(self, key: str, value: Any) -> None:
        self.steps.setdefault(key, []).append(value)


class DatasetRecorder:
    """Hooks for ``run_episodes`` that turn its rollouts into LeRobot episodes."""

    def __init__(
        self,
        writer: LeRobotWriter,
        fields: dict[str, slice],
        cameras: Sequence[str],
        image_hw: tuple[int, int],
        task_text: str,
    ) -> None:
        self.writer, self.fields, self.cameras = writer, fields, tuple(cameras)
        self.image_hw, self.task_text = image_hw, task_text
        self.estimates = [n for n, f in ESTIMATE_FIELDS.items() if f in fields]
        self._joints = fields["joint_pos"]
        self._buffers: dict[int, _EpisodeBuffer] = {}
        self._renderers: dict[int, Any] = {}

    def on_step(self, slot: int, env: gym.Env[Any, Any]) -> None:
        """Render both cameras at the state the next action is chosen on."""
        if not self.cameras:
            return
        from sim2real.rendering import FastRenderer

        base = env.unwrapped
        r = self._renderers.get(slot)
        if r is None:
            h, w = self.image_hw
            r = self._renderers[slot] = FastRenderer(base.model, w, h)  # type: ignore[attr-defined]
        buf = self._buffers.setdefault(slot, _EpisodeBuffer())
        buf.pending = {c: r.render(base.data, c).copy() for c in self.cameras}  # type: ignore[attr-defined]

    def on_transition(self, t: Transition) -> None:
        buf = self._buffers.setdefault(t.slot, _EpisodeBuffer())
        vec = np.asarray(t.obs["observation"] if isinstance(t.obs, dict) else t.obs)
        buf.add("state", vec[self._joints])
        buf.add("action", np.asarray(t.action, dtype=np.float32))
        for name in self.estimates:
            buf.add(name, vec[self.fields[ESTIMATE_FIELDS[name]]])
        buf.add("next.reward", t.reward)
        buf.add("next.success", bool(t.info.get("is_success", False)))
        buf.add("next.done", t.done)
        for cam in self.cameras:
            buf.images.setdefault(cam, []).append(buf.pending[cam])
        if t.done:
            self._flush(t.slot, bool(t.info.get("is_success", False)))

    def _flush(self, slot: int, success: bool) -> None:
        buf = self._buffers.pop(slot)
        s = buf.steps
        frames = arm_frames(
            np.stack(s["state"]),
            np.stack(s["action"]),
            {n: np.stack(s[n]) for n in self.estimates},
            {k: np.asarray(s[k]) for k in STEP_FEATURES},
        )
        images = {camera_key(c): np.stack(buf.images[c]) for c in self.cameras}
        self.writer.add_episode(frames, self.task_text, success, images)

    def close(self) -> None:
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()


def record_dataset(
    target: EvalTarget,
    out: str | Path,
    dr: DRConfig,
    seeds: list[int],
    image_hw: tuple[int, int] | None = DEFAULT_IMAGE_HW,
    progress: bool = False,
    overwrite: bool = False,
) -> tuple[Path, EvalResult, int]:
    """Roll the policy out on ``seeds`` and write a LeRobot dataset at ``out``.

    ``image_hw=None`` records no cameras. Returns (folder, result, frames written).
    """
    factory = target.env_factory(dr)
    probe = factory()
    try:
        base: Any = probe.unwrapped
        builder = getattr(base, "builder", None)
        if builder is None or getattr(base, "obs_mode", "state") == "pixels":
            raise ConfigError(
                f"--record-dataset needs a state-observation arm env; {target.env_id} has none"
            )
        fields = {f.name: slice(f.start, f.stop) for f in builder.layout()}
        spec = base.spec_arm
        joint_names = list(spec.joint_names)
        n_state = fields["joint_pos"].stop - fields["joint_pos"].start
        joint_names += [f"gripper_{i}" for i in range(n_state - len(joint_names))]
        n_act = int(probe.action_space.shape[0])  # type: ignore[index]
        action_names = (joint_names + [f"a{i}" for i in range(n_act)])[:n_act]
        cameras = [c.name for c in base.rig.cameras] if image_hw is not None else []
        fps = round(1.0 / base.control_dt_s)
        task_name = getattr(getattr(base, "task", None), "name", "")
    finally:
        probe.close()
    estimates = [n for n, f in ESTIMATE_FIELDS.items() if f in fields]
    schema = DatasetSchema(
        fps=fps,
        features=arm_features(joint_names, action_names, estimates, STEP_FEATURES),
        cameras=tuple(camera_key(c) for c in cameras),
        image_hw=image_hw or DEFAULT_IMAGE_HW,
    )
    text = TASK_TEXT.get(task_name, target.env_id)
    with LeRobotWriter(out, schema, overwrite=overwrite) as writer:
        recorder = DatasetRecorder(writer, fields, cameras, image_hw or DEFAULT_IMAGE_HW, text)
        bar = progress_bar(len(seeds), "recording", "episode", progress)

        def finished(_: Episode) -> None:
            bar.update(1)

        try:
            result = run_episodes(
                target.policy,
                factory,
                seeds,
                n_parallel=1,
                on_step=recorder.on_step,
                on_transition=recorder.on_transition,
                on_episode=finished,
            )
        finally:
            recorder.close()
            bar.close()
        frames = writer.frames
    return Path(out), result, frames
