"""The run directory: one folder holds everything a training run leaves for later.

Layout (every file written atomically)::

    RUN/
      config.json          the run's ``RunMeta`` (sim2real.runmeta): env id, task, DR preset
                           and ranges, spec + fingerprint, seeds, hyperparameters, obs layout,
                           action decoding, versions
      status.json          steps done, finished flag, wall time, latest checkpoint
      model.zip            final SB3 model (written when training finishes)
      vecnormalize.pkl     normalisation statistics (only when a VecNormalize was used: never
                           for image observations unless rewards are normalised)
      checkpoints/         step_<N>.zip (+ .vecnormalize.pkl, + .replay.pkl for the newest)
      monitor/             SB3 Monitor CSVs, one per env and training segment
      episodes.csv         every finished training episode: timestep, return, length, success
      metrics.jsonl        every logger dump (losses, entropies, Q-values ...) with its timestep
      tb/                  TensorBoard event files

Only the standard library is imported here: the deploy loop reads run configs on the robot side.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim2real.errors import RunDirError
from sim2real.runmeta import MetaError, RunMeta
from sim2real.train.atomic import atomic_write_json

CONFIG_FILE = "config.json"
STATUS_FILE = "status.json"
MODEL_FILE = "model.zip"
VECNORM_FILE = "vecnormalize.pkl"
CHECKPOINT_DIR = "checkpoints"
MONITOR_DIR = "monitor"
TB_DIR = "tb"
EPISODES_FILE = "episodes.csv"
METRICS_FILE = "metrics.jsonl"
_CKPT_RE = re.compile(r"^step_(\d+)\.zip$")


@dataclass(frozen=True)
class Checkpoint:
    steps: int
    model: Path
    vecnormalize: Path | None
    replay: Path | None


class RunDir:
    """Paths and atomic reads/writes of one run directory."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunDir({str(self.path)!r})"

    # ---- paths ------------------------------------------------------------------------------
    @property
    def config_path(self) -> Path:
        return self.path / CONFIG_FILE

    @property
    def status_path(self) -> Path:
        return self.path / STATUS_FILE

    @property
    def model_path(self) -> Path:
        return self.path / MODEL_FILE

    @property
    def vecnormalize_path(self) -> Path:
        return self.path / VECNORM_FILE

    @property
    def checkpoint_dir(self) -> Path:
        return self.path / CHECKPOINT_DIR

    @property
    def monitor_dir(self) -> Path:
        return self.path / MONITOR_DIR

    @property
    def tb_dir(self) -> Path:
        return self.path / TB_DIR

    @property
    def episodes_path(self) -> Path:
        return self.path / EPISODES_FILE

    @property
    def metrics_path(self) -> Path:
        return self.path / METRICS_FILE

    def checkpoint_paths(self, steps: int) -> Checkpoint:
        stem = f"step_{steps:010d}"
        d = self.checkpoint_dir
        return Checkpoint(
            steps, d / f"{stem}.zip", d / f"{stem}.vecnormalize.pkl", d / f"{stem}.replay.pkl"
        )

    # ---- state ------------------------------------------------------------------------------
    def has_config(self) -> bool:
        return self.config_path.is_file()

    def is_empty(self) -> bool:
        return not self.path.exists() or not any(self.path.iterdir())

    def write_meta(self, meta: RunMeta) -> None:
        atomic_write_json(self.config_path, meta.to_dict())

    def read_meta(self) -> RunMeta:
        """The run's typed record (any readable format); a missing, corrupt or unreadable
        ``config.json`` is a one-line ``RunDirError`` (naming the format when that is why)."""
        if not self.path.is_dir():
            raise RunDirError(f"run dir {str(self.path)!r} does not exist")
        if not self.config_path.is_file():
            raise RunDirError(f"run dir {str(self.path)!r} has no {CONFIG_FILE}: not a run dir")
        try:
            data = json.loads(self.config_path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            msg = str(exc).splitlines()[0]
            raise RunDirError(
                f"run dir {str(self.path)!r}: corrupt {CONFIG_FILE} ({msg})"
            ) from None
        try:
            return RunMeta.from_dict(data, source=str(self.path))
        except MetaError as exc:
            raise RunDirError(str(exc).replace("metadata of", "run dir", 1)) from None

    def write_config(self, config: Mapping[str, Any]) -> None:
        """A record given as its JSON mapping: checked by ``RunMeta`` before it is written."""
        try:
            meta = RunMeta.from_dict(config, source=str(self.path))
        except MetaError as exc:
            raise RunDirError(str(exc).replace("metadata of", "run dir", 1)) from None
        self.write_meta(meta)

    def read_config(self) -> dict[str, Any]:
        """``read_meta()`` as its JSON mapping (the current format, whatever the file's)."""
        return self.read_meta().to_dict()

    def read_status(self) -> dict[str, Any]:
        if not self.status_path.is_file():
            return {"steps_done": 0, "finished": False, "wall_s": 0.0, "segments": 0}
        try:
            data = json.loads(self.status_path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            msg = str(exc).splitlines()[0]
            raise RunDirError(
                f"run dir {str(self.path)!r}: corrupt {STATUS_FILE} ({msg})"
            ) from None
        if not isinstance(data, dict):
            raise RunDirError(f"run dir {str(self.path)!r}: {STATUS_FILE} is not a mapping")
        return data

    def write_status(self, status: dict[str, Any]) -> None:
        atomic_write_json(self.status_path, status)

    def checkpoints(self) -> list[Checkpoint]:
        """Complete checkpoints (model file present), oldest first."""
        out: list[Checkpoint] = []
        if not self.checkpoint_dir.is_dir():
            return out
        for p in self.checkpoint_dir.iterdir():
            m = _CKPT_RE.match(p.name)
            if m:
                c = self.checkpoint_paths(int(m.group(1)))
                out.append(
                    Checkpoint(
                        c.steps,
                        c.model,
                        c.vecnormalize if c.vecnormalize and c.vecnormalize.is_file() else None,
                        c.replay if c.replay and c.replay.is_file() else None,
                    )
                )
        return sorted(out, key=lambda c: c.steps)

    def latest_checkpoint(self) -> Checkpoint | None:
        ckpts = self.checkpoints()
        return ckpts[-1] if ckpts else None

    def policy_files(self) -> tuple[Path, Path | None]:
        """(model, vecnormalize-or-None) of the final model, else of the newest checkpoint.

        Runs without observation normalisation (pixels) have no vecnormalize file; a run whose
        config says it normalised observations must have one, or its policy would see raw inputs.
        """
        meta = self.read_meta()
        if self.model_path.is_file():
            model, vn = self.model_path, self.vecnormalize_path
            found = vn if vn.is_file() else None
        else:
            ckpt = self.latest_checkpoint()
            if ckpt is None:
                raise RunDirError(
                    f"run dir {str(self.path)!r} has neither {MODEL_FILE} nor a checkpoint"
                )
            model, found = ckpt.model, ckpt.vecnormalize
        norm = meta.vecnormalize  # None in older configs: nothing to check
        if found is None and norm is not None and norm.get("norm_obs"):
            raise RunDirError(
                f"run dir {str(self.path)!r}: {model.name} was trained on normalised "
                f"observations but its {VECNORM_FILE} is missing"
            )
        return model, found
