"""Watching a policy: an MP4 from the rig's camera (imageio-ffmpeg) or the MuJoCo viewer."""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from sim2real.errors import ConfigError, Sim2RealError
from sim2real.evaluate.core import EvalTarget
from sim2real.evaluate.rollout import EvalResult, run_episodes
from sim2real.randomization import DRConfig

VIDEO_SUFFIXES: tuple[str, ...] = (".mp4", ".mkv", ".avi", ".mov")


def record_video(
    target: EvalTarget,
    path: str | Path,
    dr: DRConfig,
    seeds: list[int],
    camera: str = "cam_left",
    width: int = 640,
    height: int = 480,
) -> tuple[Path, EvalResult]:
    """Rollouts rendered from ``camera`` into one video file, written atomically."""
    import imageio.v2 as imageio

    out = Path(path)
    if out.suffix.lower() not in VIDEO_SUFFIXES:
        raise ConfigError(f"video file {str(out)!r} must end in one of {', '.join(VIDEO_SUFFIXES)}")
    if width % 16 or height % 16:
        raise ConfigError(f"video size {width}x{height} must be a multiple of 16 (H.264 blocks)")
    out.parent.mkdir(parents=True, exist_ok=True)
    probe = target.env_factory(dr)()
    fps = round(1.0 / probe.unwrapped.control_dt_s)  # type: ignore[attr-defined]
    probe.close()
    factory = target.env_factory(
        dr, render_mode="rgb_array", camera=camera, render_width=width, render_height=height
    )
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=out.suffix, dir=out.parent)
    os.close(fd)
    writer = imageio.get_writer(tmp, fps=fps, macro_block_size=16)
    try:

        def grab(slot: int, env: gym.Env[Any, Any]) -> None:
            frame = env.render()
            if frame is not None:
                writer.append_data(np.asarray(frame))

        result = run_episodes(target.policy, factory, seeds, n_parallel=1, on_step=grab)
        writer.close()
        os.replace(tmp, out)
    except BaseException:
        writer.close()
        Path(tmp).unlink(missing_ok=True)
        raise
    return out, result


def has_display() -> bool:
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def view_human(target: EvalTarget, dr: DRConfig, seeds: list[int]) -> EvalResult:
    """Episodes in the interactive MuJoCo viewer, paced at the control rate."""
    if not has_display():
        raise Sim2RealError(
            "--render human needs a display (DISPLAY is unset); use --video FILE.mp4"
        )
    import mujoco.viewer

    handles: dict[int, Any] = {}

    def show(slot: int, env: gym.Env[Any, Any]) -> None:
        u: Any = env.unwrapped
        if slot not in handles:
            handles[slot] = mujoco.viewer.launch_passive(u.model, u.data)
        if not handles[slot].is_running():
            raise KeyboardInterrupt
        handles[slot].sync()
        time.sleep(u.control_dt_s)

    try:
        return run_episodes(
            target.policy, target.env_factory(dr), seeds, n_parallel=1, on_step=show
        )
    finally:
        for h in handles.values():
            h.close()
