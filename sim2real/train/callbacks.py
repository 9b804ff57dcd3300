"""Callbacks of a training run: progress bar, atomic checkpoints, episode log, metrics log."""

from __future__ import annotations

import csv
import io
import json
import math
import pickle
import sys
import time
from pathlib import Path
from typing import IO, Any, cast

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import KVWriter

from sim2real.train.atomic import atomic_write
from sim2real.train.rundir import Checkpoint, RunDir

EPISODE_FIELDS: tuple[str, ...] = (
    "timesteps",
    "env",
    "return",
    "length",
    "is_success",
    "distance_m",
    "wall_s",
)


class ProgressBar(BaseCallback):
    """tqdm bar over env steps with the recent training success rate and steps/s."""

    def __init__(self, total_steps: int, enabled: bool = True, refresh_s: float = 0.5) -> None:
        super().__init__()
        self.total = total_steps
        self.enabled = enabled
        self.refresh_s = refresh_s
        self._bar: Any = None
        self._last = 0.0
        self._t0 = 0.0
        self._n0 = 0

    def _on_training_start(self) -> None:
        from tqdm import tqdm

        from sim2real.progress import progress_enabled

        self._t0 = time.perf_counter()
        self._n0 = self.model.num_timesteps
        self._bar = tqdm(
            total=self.total,
            initial=self._n0,
            unit="step",
            dynamic_ncols=True,
            file=sys.stderr,
            disable=not progress_enabled(self.enabled),  # quiet off a terminal and in CI
            smoothing=0.1,
        )

    def _on_step(self) -> bool:
        now = time.perf_counter()
        if now - self._last >= self.refresh_s:
            self._refresh(now)
        return True

    def _refresh(self, now: float) -> None:
        self._last = now
        n = self.model.num_timesteps
        self._bar.update(min(n, self.total) - self._bar.n)
        succ = self.model.ep_success_buffer
        rate = (n - self._n0) / max(now - self._t0, 1e-9)
        postfix = {"success": f"{np.mean(succ):.0%}" if succ else "-", "steps/s": f"{rate:.0f}"}
        self._bar.set_postfix(ordered_dict=postfix, refresh=False)

    def _on_training_end(self) -> None:
        if self._bar is not None:
            self._refresh(time.perf_counter())
            self._bar.close()


def save_checkpoint(
    model: BaseAlgorithm, rd: RunDir, save_replay: bool, keep: int = 2
) -> Checkpoint:
    """Model last: a checkpoint counts as complete once its .zip exists."""
    ckpt = rd.checkpoint_paths(int(model.num_timesteps))
    vn = model.get_vec_normalize_env()
    if vn is not None and ckpt.vecnormalize is not None:
        atomic_write(ckpt.vecnormalize, lambda fh: pickle.dump(vn, fh))
    if save_replay and getattr(model, "replay_buffer", None) is not None and ckpt.replay:
        atomic_write(ckpt.replay, model.save_replay_buffer)  # type: ignore[attr-defined]
    atomic_write(ckpt.model, lambda fh: model.save(cast(io.BufferedIOBase, fh)))
    older = [c for c in rd.checkpoints() if c.steps < ckpt.steps]
    for c in older:  # a replay buffer is only worth keeping for the newest checkpoint
        if c.replay is not None:
            c.replay.unlink(missing_ok=True)
    for c in older[: max(len(older) - (keep - 1), 0)]:
        for p in (c.model, c.vecnormalize):
            if p is not None:
                p.unlink(missing_ok=True)
    return ckpt


class WallClockLimit(BaseCallback):
    """Stops training after ``limit_s`` of wall time in this segment ("train for 10 minutes")."""

    def __init__(self, limit_s: float) -> None:
        super().__init__()
        self.limit_s = limit_s
        self.hit = False
        self._t0 = 0.0

    def _on_training_start(self) -> None:
        self._t0 = time.perf_counter()

    def _on_step(self) -> bool:
        self.hit = self.limit_s > 0 and time.perf_counter() - self._t0 >= self.limit_s
        return not self.hit


class RunDirCheckpoint(BaseCallback):
    """Every ``interval`` env steps (at a rollout boundary), an atomic checkpoint + status."""

    def __init__(self, rd: RunDir, interval: int, save_replay: bool, on_save: Any) -> None:
        super().__init__()
        self.rd = rd
        self.interval = interval
        self.save_replay = save_replay
        self.on_save = on_save
        self._next = 0

    def _on_training_start(self) -> None:
        n = self.model.num_timesteps
        self._next = (n // self.interval + 1) * self.interval

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        if self.model.num_timesteps >= self._next:
            ckpt = save_checkpoint(self.model, self.rd, self.save_replay)
            self.on_save(ckpt)
            n = self.model.num_timesteps
            self._next = (n // self.interval + 1) * self.interval


class EpisodeLog(BaseCallback):
    """Appends one CSV row per finished training episode, stamped with the global timestep."""

    def __init__(self, path: Path, wall_offset_s: float = 0.0) -> None:
        super().__init__()
        self.path = path
        self.wall_offset_s = wall_offset_s
        self._fh: IO[str] | None = None
        self._writer: Any = None
        self._t0 = 0.0

    def _on_training_start(self) -> None:
        new = not self.path.is_file()
        self._fh = self.path.open("a", newline="")
        self._writer = csv.writer(self._fh)
        if new:
            self._writer.writerow(EPISODE_FIELDS)
        self._t0 = time.perf_counter()

    def _on_step(self) -> bool:
        infos = self.locals.get("infos", ())
        dones = self.locals.get("dones", ())
        for i, (info, done) in enumerate(zip(infos, dones, strict=False)):
            ep = info.get("episode") if done else None
            if ep is not None:
                self._writer.writerow(
                    (
                        self.model.num_timesteps,
                        i,
                        f"{float(ep['r']):.6g}",
                        int(ep["l"]),
                        int(bool(info.get("is_success", False))),
                        f"{float(info.get('distance_m', math.nan)):.6g}",
                        f"{self.wall_offset_s + time.perf_counter() - self._t0:.3f}",
                    )
                )
        return True

    def _on_rollout_end(self) -> None:
        if self._fh is not None:
            self._fh.flush()

    def _on_training_end(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None


class JsonlMetrics(KVWriter):
    """SB3 logger output: one JSON line of numeric values per dump, keyed by timestep."""

    def __init__(self, path: Path) -> None:
        self._fh = path.open("a")

    def write(
        self, key_values: dict[str, Any], key_excluded: dict[str, Any], step: int = 0
    ) -> None:
        row: dict[str, float] = {"timesteps": float(step)}
        for k, v in key_values.items():
            if isinstance(v, int | float | np.floating | np.integer) and not isinstance(v, bool):
                row[k] = float(v)
        self._fh.write(json.dumps(row) + "\n")
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()
