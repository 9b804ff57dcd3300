"""Write and read rollouts as a LeRobot dataset (format v3.0), the format hobby-arm users share.

The layout is the one LeRobot's own ``LeRobotDataset`` loads (checked by ``bench/lerobot_dataset.py``
against the ``lerobot-dataset`` package)::

    meta/info.json                                   features, fps, counts, path templates
    meta/stats.json                                  min/max/mean/std/count per feature
    meta/tasks.parquet                               task string (pandas index "task") -> task_index
    meta/episodes/chunk-000/file-000.parquet         one row per episode: lengths, file offsets,
                                                     video time spans, per-episode stats, success
    data/chunk-000/file-000.parquet                  one row per frame
    videos/<camera key>/chunk-000/file-000.mp4       every episode of one camera, back to back

Episodes are concatenated in one data file and one video per camera, as LeRobot v3.0 does; an
episode's video frames are found through its ``from_timestamp``. Parquet goes through pyarrow,
video through imageio-ffmpeg's FFmpeg (H.264, a key frame every 2 frames as LeRobot encodes, so
seeking to any frame is cheap). The dataset is written in a temporary folder beside the target
and renamed into place when it is complete: a crash never leaves half a dataset.

The writer takes a dict of per-step arrays per episode, so that any loop that logs steps (the
evaluation rollouts, the deploy loop) can record: ``arm_features`` / ``arm_frames`` give the
standard arm keys (joint state, action, named position estimates, cameras), and
``split_episodes`` cuts a flat per-period log (the deploy loop's) into episodes::

    schema = DatasetSchema(fps=20, features=arm_features(joints, joints, ["tool", "goal"]))
    with LeRobotWriter("datasets/run1", schema) as writer:
        for rows, ok in zip(split_episodes(log), successes):
            est = {"tool": rows["ee_est_m"], "goal": rows["goal_est_m"]}
            writer.add_episode(arm_frames(rows["joints_rad"], rows["action"], est), task, ok)
"""

from __future__ import annotations

import itertools
import json
import math
import os
import shutil
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from sim2real.errors import ConfigError, Sim2RealError

CODEBASE_VERSION = "v3.0"
CHUNK_FILE = "chunk-{chunk_index:03d}/file-{file_index:03d}"
DATA_PATH = "data/" + CHUNK_FILE + ".parquet"
VIDEO_PATH = "videos/{video_key}/" + CHUNK_FILE + ".mp4"
EPISODES_PATH = "meta/episodes/" + CHUNK_FILE + ".parquet"
INFO_PATH, STATS_PATH, TASKS_PATH = "meta/info.json", "meta/stats.json", "meta/tasks.parquet"
# LeRobot's defaults, recorded in info.json (readers use the path templates, not the limits).
CHUNKS_SIZE, DATA_FILE_MB, VIDEO_FILE_MB = 1000, 100, 200
# Columns every LeRobot frame carries; the writer fills them.
INDEX_FEATURES: dict[str, str] = {
    "timestamp": "float32",
    "frame_index": "int64",
    "episode_index": "int64",
    "index": "int64",
    "task_index": "int64",
}
DTYPES: tuple[str, ...] = ("float32", "float64", "int64", "bool")
IMAGE_PREFIX = "observation.images."
# LeRobot's language task per sim2real task (the deploy recorder's and evaluate's episodes say
# the same); an unknown task falls back to its own name or env id.
TASK_TEXT: dict[str, str] = {
    "reach": "move the tool tip to the target",
    "pick": "pick up the cube and lift it to the goal",
    "trace": "follow the seam with the tool tip",
}
VIDEO_CODEC, VIDEO_GOP, VIDEO_CRF = "libx264", 2, 23
# Frames sampled per episode and camera for the image statistics (LeRobot samples too).
IMAGE_STATS_SAMPLES = 20


class DatasetError(Sim2RealError):
    """A dataset that cannot be written or read as asked."""


@dataclass(frozen=True)
class Feature:
    """One per-frame array: its shape, dtype, and a name per element (LeRobot's ``names``)."""

    shape: tuple[int, ...]
    dtype: str = "float32"
    names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if self.dtype not in DTYPES:
            raise ConfigError(f"feature dtype {self.dtype!r} not one of {', '.join(DTYPES)}")
        if len(self.shape) != 1 or self.shape[0] < 1:
            raise ConfigError(f"feature shape {self.shape} must be (n,) with n >= 1")
        if self.names is not None and len(self.names) != self.shape[0]:
            raise ConfigError(f"feature names {self.names} do not match its shape {self.shape}")

    def to_info(self) -> dict[str, Any]:
        return {"dtype": self.dtype, "shape": list(self.shape), "names": _names(self.names)}


def _names(names: tuple[str, ...] | None) -> list[str] | None:
    return None if names is None else list(names)


@dataclass(frozen=True)
class DatasetSchema:
    """What every frame of a dataset carries; validated on construction."""

    fps: int
    features: Mapping[str, Feature]
    cameras: tuple[str, ...] = ()  # video keys, e.g. "observation.images.cam_left"
    image_hw: tuple[int, int] = (240, 320)
    robot_type: str = "sim2real_arm3"
    _all: tuple[str, ...] = field(init=False, repr=False, default=())

    def __post_init__(self) -> None:
        if not 1 <= self.fps <= 1000:
            raise ConfigError(f"dataset fps {self.fps} not in [1, 1000]")
        h, w = self.image_hw
        if self.cameras and (h < 16 or w < 16 or h % 2 or w % 2):
            raise ConfigError(f"image size {w}x{h} must be even and at least 16x16 (H.264)")
        keys = [*self.features, *self.cameras]
        for key in keys:
            if not key or "/" in key or key in INDEX_FEATURES:
                raise ConfigError(
                    f"feature key {key!r} is empty, has '/', or is one of {sorted(INDEX_FEATURES)}"
                )
        if len(set(keys)) != len(keys):
            raise ConfigError(f"feature keys repeat: {keys}")
        object.__setattr__(self, "_all", tuple(keys))

    def info_features(self) -> dict[str, Any]:
        h, w = self.image_hw
        out: dict[str, Any] = {k: f.to_info() for k, f in self.features.items()}
        for cam in self.cameras:
            out[cam] = {
                "dtype": "video",
                "shape": [h, w, 3],
                "names": ["height", "width", "channels"],
                "info": {
                    "video.height": h,
                    "video.width": w,
                    "video.codec": "h264",
                    "video.pix_fmt": "yuv420p",
                    "video.is_depth_map": False,
                    "video.fps": self.fps,
                    "video.channels": 3,
                    "has_audio": False,
                },
            }
        for key, dtype in INDEX_FEATURES.items():
            out[key] = {"dtype": dtype, "shape": [1], "names": None}
        return out


# ---- the standard arm keys ----------------------------------------------------------------
def camera_key(name: str) -> str:
    return IMAGE_PREFIX + name


def arm_features(
    joint_names: Sequence[str],
    action_names: Sequence[str],
    estimates: Sequence[str] = (),
    extras: Mapping[str, Feature] | None = None,
) -> dict[str, Feature]:
    """``observation.state`` (joint readings, rad), ``action``, one ``observation.<name>_pos``
    (base frame, m) per position estimate (tool, goal, cube), plus any extra features."""
    xyz = ("x", "y", "z")
    feats = {
        "observation.state": Feature((len(joint_names),), names=tuple(joint_names)),
        "action": Feature((len(action_names),), names=tuple(action_names)),
    }
    for name in estimates:
        feats[f"observation.{name}_pos"] = Feature((3,), names=xyz)
    feats.update(extras or {})
    return feats


def arm_frames(
    state: np.ndarray,
    action: np.ndarray,
    estimates: Mapping[str, np.ndarray] | None = None,
    extras: Mapping[str, np.ndarray] | None = None,
) -> dict[str, np.ndarray]:
    """The per-step arrays of one episode under the keys ``arm_features`` declares."""
    frames = {"observation.state": np.asarray(state), "action": np.asarray(action)}
    for name, value in (estimates or {}).items():
        frames[f"observation.{name}_pos"] = np.asarray(value)
    frames.update({k: np.asarray(v) for k, v in (extras or {}).items()})
    return frames


def split_episodes(
    log: Mapping[str, np.ndarray], episode_key: str = "episode"
) -> list[dict[str, np.ndarray]]:
    """A flat per-step log (one row per control period, an episode number per row, as the
    deploy loop's ``LoopLog`` saves it) as one dict of per-step arrays per episode, in order.

    Keys whose length differs from the episode column (per-run values) are left out.
    """
    if episode_key not in log:
        raise DatasetError(f"log has no {episode_key!r} column; keys: {sorted(log)}")
    ep = np.asarray(log[episode_key])
    n = len(ep)
    per_step = {k: np.asarray(v) for k, v in log.items() if np.ndim(v) >= 1 and len(v) == n}
    starts = np.flatnonzero(np.r_[True, ep[1:] != ep[:-1]]) if n else np.array([], int)
    bounds = [*starts.tolist(), n]
    return [{k: v[a:b] for k, v in per_step.items()} for a, b in itertools.pairwise(bounds)]


# ---- statistics --------------------------------------------------------------------------
class _RunningStats:
    """min/max/mean/std/count over frames (NaN-aware: a lost estimate does not poison a mean)."""

    def __init__(self, shape: tuple[int, ...]) -> None:
        self.n = np.zeros(shape)
        self.s = np.zeros(shape)
        self.ss = np.zeros(shape)
        self.lo = np.full(shape, np.inf)
        self.hi = np.full(shape, -np.inf)
        self.frames = 0

    def add(self, x: np.ndarray) -> None:
        """``x``: (frames, *shape)."""
        x = x.astype(np.float64)
        ok = np.isfinite(x)
        self.n += ok.sum(0)
        self.s += np.where(ok, x, 0.0).sum(0)
        self.ss += np.where(ok, x * x, 0.0).sum(0)
        self.lo = np.fmin(self.lo, np.where(ok, x, np.inf).min(0))
        self.hi = np.fmax(self.hi, np.where(ok, x, -np.inf).max(0))
        self.frames += len(x)

    def to_dict(self) -> dict[str, Any]:
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = self.s / self.n
            std = np.sqrt(np.maximum(self.ss / self.n - mean * mean, 0.0))
        nan = self.n == 0
        lo, hi = np.where(nan, np.nan, self.lo), np.where(nan, np.nan, self.hi)
        return {
            "min": lo.tolist(),
            "max": hi.tolist(),
            "mean": mean.tolist(),
            "std": std.tolist(),
            "count": [int(self.frames)],
        }


def _image_samples(frames: np.ndarray) -> np.ndarray:
    """(k, 3, 1, 1)-ready per-channel pixels in [0, 1] from a few evenly spaced frames."""
    idx = np.unique(np.linspace(0, len(frames) - 1, min(IMAGE_STATS_SAMPLES, len(frames))).round())
    sample = frames[idx.astype(int)].astype(np.float64) / 255.0  # (k, h, w, 3)
    return sample.transpose(0, 3, 1, 2).reshape(len(idx), 3, -1)  # (k, 3, h*w)


class _ImageStats:
    """Per-channel stats in [0, 1], shaped (3, 1, 1) as LeRobot stores them for cameras."""

    def __init__(self) -> None:
        self.run = _RunningStats((3,))
        self.frames = 0

    def add(self, frames: np.ndarray) -> None:
        px = _image_samples(frames)  # (k, 3, p)
        self.run.add(px.transpose(0, 2, 1).reshape(-1, 3))
        self.frames += len(frames)

    def to_dict(self) -> dict[str, Any]:
        d = self.run.to_dict()
        out: dict[str, Any] = {k: [[[v]] for v in d[k]] for k in ("min", "max", "mean", "std")}
        out["count"] = [int(self.frames)]
        return out


# ---- the writer ----------------------------------------------------------------------------
class _VideoStream:
    """One camera's MP4: every episode appended, frame timestamps i / fps."""

    def __init__(self, path: Path, hw: tuple[int, int], fps: int) -> None:
        import imageio_ffmpeg

        path.parent.mkdir(parents=True, exist_ok=True)
        self.hw, self.frames = hw, 0
        self._gen = imageio_ffmpeg.write_frames(
            str(path),
            (hw[1], hw[0]),
            fps=fps,
            codec=VIDEO_CODEC,
            pix_fmt_in="rgb24",
            pix_fmt_out="yuv420p",
            quality=None,
            macro_block_size=1,
            ffmpeg_log_level="error",
            output_params=["-g", str(VIDEO_GOP), "-crf", str(VIDEO_CRF), "-bf", "0"],
        )
        self._gen.send(None)

    def write(self, frames: np.ndarray) -> None:
        for frame in frames:
            self._gen.send(np.ascontiguousarray(frame, dtype=np.uint8))
        self.frames += len(frames)

    def close(self) -> None:
        self._gen.close()


class LeRobotWriter:
    """Collects episodes into a LeRobot v3.0 dataset at ``root``, written atomically.

    Use as a context manager: a clean exit finalises and moves the dataset into place; an error
    removes the temporary folder and leaves any existing ``root`` untouched.
    """

    def __init__(self, root: str | Path, schema: DatasetSchema, overwrite: bool = False) -> None:
        import pyarrow.parquet as pq

        self.root = Path(root)
        if self.root.exists() and not overwrite:
            raise DatasetError(f"dataset folder {str(self.root)!r} exists; choose a new one")
        self.root.parent.mkdir(parents=True, exist_ok=True)
        self.schema, self.overwrite = schema, overwrite
        self._tmp = Path(tempfile.mkdtemp(prefix=f".{self.root.name}.", dir=self.root.parent))
        self._arrow = _arrow_schema(schema)
        self._videos: dict[str, _VideoStream] = {}
        try:
            data_file = self._tmp / DATA_PATH.format(chunk_index=0, file_index=0)
            data_file.parent.mkdir(parents=True)
            self._data = pq.ParquetWriter(data_file, self._arrow, compression="snappy")
            for cam in schema.cameras:
                self._videos[cam] = _VideoStream(
                    self._tmp / VIDEO_PATH.format(video_key=cam, chunk_index=0, file_index=0),
                    schema.image_hw,
                    schema.fps,
                )
        except BaseException:  # no encoder, disk full: leave no temporary folder behind
            for video in self._videos.values():
                video.close()
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise
        self._stats: dict[str, _RunningStats | _ImageStats] = {
            k: _RunningStats(f.shape) for k, f in schema.features.items()
        }
        self._stats.update({cam: _ImageStats() for cam in schema.cameras})
        self._stats.update({k: _RunningStats((1,)) for k in INDEX_FEATURES})
        self._tasks: dict[str, int] = {}
        self._episodes: list[dict[str, Any]] = []
        self._frames = 0
        self._closed = False

    @property
    def episodes(self) -> int:
        return len(self._episodes)

    @property
    def frames(self) -> int:
        return self._frames

    def add_episode(
        self,
        frames: Mapping[str, np.ndarray],
        task: str,
        success: bool,
        images: Mapping[str, np.ndarray] | None = None,
    ) -> int:
        """Append one episode; returns its index.

        ``frames``: every schema feature as a (T, n) array (T steps; (T,) for n = 1).
        ``images``: every schema camera as (T, H, W, 3) uint8 RGB. ``task``: what the episode
        was asked to do (LeRobot's language task); ``success``: whether it did.
        """
        if self._closed:
            raise DatasetError("dataset already closed")
        if not task.strip():
            raise DatasetError("task string is empty; say what the episode does")
        columns, length = self._check_frames(frames)
        shots = self._check_images(images or {}, length)
        ep = len(self._episodes)
        task_index = self._tasks.setdefault(task, len(self._tasks))
        index_cols: dict[str, np.ndarray] = {
            "timestamp": (np.arange(length) / self.schema.fps).astype(np.float32),
            "frame_index": np.arange(length, dtype=np.int64),
            "episode_index": np.full(length, ep, dtype=np.int64),
            "index": np.arange(self._frames, self._frames + length, dtype=np.int64),
            "task_index": np.full(length, task_index, dtype=np.int64),
        }
        self._data.write_table(_table(self._arrow, {**columns, **index_cols}))

        row: dict[str, Any] = {
            "episode_index": ep,
            "tasks": [task],
            "length": length,
            "success": bool(success),
            "data/chunk_index": 0,
            "data/file_index": 0,
            "dataset_from_index": self._frames,
            "dataset_to_index": self._frames + length,
        }
        for cam, video in self._videos.items():
            start = video.frames
            video.write(shots[cam])
            row[f"videos/{cam}/chunk_index"] = 0
            row[f"videos/{cam}/file_index"] = 0
            row[f"videos/{cam}/from_timestamp"] = start / self.schema.fps
            row[f"videos/{cam}/to_timestamp"] = video.frames / self.schema.fps
        row["meta/episodes/chunk_index"] = 0
        row["meta/episodes/file_index"] = 0
        # Per-episode statistics, as LeRobot keeps them (its merge and aggregate tools use them).
        for key, values in [*columns.items(), *index_cols.items()]:
            ep_stats = _RunningStats(values.shape[1:] or (1,))
            ep_stats.add(values.reshape(length, -1))
            self._stats[key].add(values.reshape(length, -1))
            for stat, v in ep_stats.to_dict().items():
                row[f"stats/{key}/{stat}"] = v
        for cam in self.schema.cameras:
            cam_stats = _ImageStats()
            cam_stats.add(shots[cam])
            self._stats[cam].add(shots[cam])
            for stat, v in cam_stats.to_dict().items():
                row[f"stats/{cam}/{stat}"] = v
        self._episodes.append(row)
        self._frames += length
        return ep

    def _check_frames(self, frames: Mapping[str, np.ndarray]) -> tuple[dict[str, np.ndarray], int]:
        missing = sorted(set(self.schema.features) - set(frames))
        extra = sorted(set(frames) - set(self.schema.features))
        if missing or extra:
            raise DatasetError(f"episode keys: missing {missing}, unexpected {extra}")
        out: dict[str, np.ndarray] = {}
        lengths: set[int] = set()
        for key, feat in self.schema.features.items():
            a = np.asarray(frames[key])
            if a.ndim == 1 and feat.shape == (1,):
                a = a[:, None]
            if a.ndim != 2 or a.shape[1:] != feat.shape:
                raise DatasetError(f"{key}: shape {a.shape}, expected (T, {feat.shape[0]})")
            out[key] = a.astype(feat.dtype)
            lengths.add(len(a))
        if len(lengths) != 1 or 0 in lengths:
            raise DatasetError(f"episode arrays have lengths {sorted(lengths)}; need one T >= 1")
        return out, lengths.pop()

    def _check_images(self, images: Mapping[str, np.ndarray], length: int) -> dict[str, np.ndarray]:
        if sorted(images) != sorted(self.schema.cameras):
            raise DatasetError(f"episode cameras {sorted(images)}, expected {self.schema.cameras}")
        want = (length, *self.schema.image_hw, 3)
        out = {}
        for cam, frames in images.items():
            a = np.asarray(frames)
            if a.shape != want or a.dtype != np.uint8:
                raise DatasetError(f"{cam}: frames {a.shape} {a.dtype}, expected {want} uint8")
            out[cam] = a
        return out

    def close(self) -> Path:
        """Write the metadata and move the finished dataset into place; returns its folder."""
        if self._closed:
            return self.root
        if not self._episodes:
            raise DatasetError("no episode recorded; a dataset needs at least one")
        self._data.close()
        for video in self._videos.values():
            video.close()
        self._write_meta()
        self._closed = True
        _replace_dir(self._tmp, self.root, self.overwrite)
        return self.root

    def abort(self) -> None:
        """Drop everything written so far."""
        if self._closed:
            return
        self._closed = True
        try:
            self._data.close()
            for video in self._videos.values():
                video.close()
        finally:
            shutil.rmtree(self._tmp, ignore_errors=True)

    def __enter__(self) -> LeRobotWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def _write_meta(self) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        n_ep = len(self._episodes)
        info = {
            "codebase_version": CODEBASE_VERSION,
            "robot_type": self.schema.robot_type,
            "total_episodes": n_ep,
            "total_frames": self._frames,
            "total_tasks": len(self._tasks),
            "chunks_size": CHUNKS_SIZE,
            "data_files_size_in_mb": DATA_FILE_MB,
            "video_files_size_in_mb": VIDEO_FILE_MB,
            "fps": self.schema.fps,
            "splits": {"train": f"0:{n_ep}"},
            "data_path": DATA_PATH,
            "video_path": VIDEO_PATH if self.schema.cameras else None,
            "features": self.schema.info_features(),
        }
        meta = self._tmp / "meta"
        meta.mkdir(exist_ok=True)
        (self._tmp / INFO_PATH).write_text(json.dumps(info, indent=2) + "\n")
        stats = {k: s.to_dict() for k, s in self._stats.items()}
        (self._tmp / STATS_PATH).write_text(json.dumps(stats, indent=2, allow_nan=True) + "\n")
        # pandas reads the index back from this metadata: LeRobot looks tasks up by string.
        tasks = pa.table(
            {
                "task_index": pa.array(list(self._tasks.values()), pa.int64()),
                "task": pa.array(list(self._tasks), pa.string()),
            }
        ).replace_schema_metadata({"pandas": json.dumps(_PANDAS_TASKS_META)})
        pq.write_table(tasks, self._tmp / TASKS_PATH)
        episodes_file = self._tmp / EPISODES_PATH.format(chunk_index=0, file_index=0)
        episodes_file.parent.mkdir(parents=True)
        pq.write_table(pa.Table.from_pylist(self._episodes), episodes_file)


_PANDAS_TASKS_META: dict[str, Any] = {
    "index_columns": ["task"],
    "column_indexes": [
        {
            "name": None,
            "field_name": None,
            "pandas_type": "unicode",
            "numpy_type": "object",
            "metadata": {"encoding": "UTF-8"},
        }
    ],
    "columns": [
        {
            "name": "task_index",
            "field_name": "task_index",
            "pandas_type": "int64",
            "numpy_type": "int64",
            "metadata": None,
        },
        {
            "name": "task",
            "field_name": "task",
            "pandas_type": "unicode",
            "numpy_type": "object",
            "metadata": None,
        },
    ],
    "creator": {"library": "pyarrow", "version": "15"},
    "pandas_version": "2.0.0",
}


def _arrow_schema(schema: DatasetSchema) -> Any:
    """Scalars for shape (1,) features, fixed-size lists otherwise: what LeRobot's loader casts
    its ``datasets`` features to (``Value`` and ``Sequence(length=n)``)."""
    import pyarrow as pa

    def arrow_type(dtype: str) -> Any:
        return {"float32": pa.float32(), "float64": pa.float64(), "int64": pa.int64()}.get(
            dtype, pa.bool_()
        )

    fields = []
    for key, feat in schema.features.items():
        t = arrow_type(feat.dtype)
        fields.append(pa.field(key, t if feat.shape == (1,) else pa.list_(t, feat.shape[0])))
    fields += [pa.field(k, arrow_type(d)) for k, d in INDEX_FEATURES.items()]
    return pa.schema(fields)


def _table(arrow_schema: Any, columns: Mapping[str, np.ndarray]) -> Any:
    import pyarrow as pa

    arrays = []
    for f in arrow_schema:
        values = np.asarray(columns[f.name])
        if pa.types.is_fixed_size_list(f.type):
            flat = pa.array(values.reshape(-1), f.type.value_type)
            arrays.append(pa.FixedSizeListArray.from_arrays(flat, f.type.list_size))
        else:
            arrays.append(pa.array(values.reshape(-1), f.type))
    return pa.Table.from_arrays(arrays, schema=arrow_schema)


def _replace_dir(tmp: Path, root: Path, overwrite: bool) -> None:
    """Rename the finished folder into place (an old one only after the new one is complete)."""
    if root.exists():
        if not overwrite:
            shutil.rmtree(tmp, ignore_errors=True)
            raise DatasetError(f"dataset folder {str(root)!r} appeared while writing")
        old = Path(tempfile.mkdtemp(prefix=f".{root.name}.old.", dir=root.parent))
        os.replace(root, old / root.name)
        os.replace(tmp, root)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, root)


# ---- reading back --------------------------------------------------------------------------
@dataclass(frozen=True)
class EpisodeInfo:
    index: int
    length: int
    task: str
    success: bool | None


@dataclass(frozen=True)
class LeRobotDataset:
    """A dataset read back with pyarrow: metadata, episodes, frames; video frames on demand."""

    root: Path
    info: dict[str, Any]
    episodes: tuple[EpisodeInfo, ...]
    _episode_rows: tuple[dict[str, Any], ...]

    @classmethod
    def open(cls, root: str | Path) -> LeRobotDataset:
        import pyarrow.parquet as pq

        path = Path(root)
        info_file = path / INFO_PATH
        if not info_file.is_file():
            raise DatasetError(f"{str(path)!r} is not a LeRobot dataset (no {INFO_PATH})")
        info = json.loads(info_file.read_text())
        version = str(info.get("codebase_version"))
        if version != CODEBASE_VERSION:
            raise DatasetError(
                f"{str(path)!r} is LeRobot format {version}; this reader reads {CODEBASE_VERSION}"
            )
        tasks_tab = pq.read_table(path / TASKS_PATH).to_pylist()
        task_names = {int(r["task_index"]): str(r.get("task", "")) for r in tasks_tab}
        files = sorted((path / "meta" / "episodes").glob("*/*.parquet"))
        rows = [r for f in files for r in pq.read_table(f).to_pylist()]
        rows.sort(key=lambda r: int(r["episode_index"]))
        episodes = tuple(
            EpisodeInfo(
                int(r["episode_index"]),
                int(r["length"]),
                ", ".join(r.get("tasks") or [task_names.get(0, "")]),
                None if r.get("success") is None else bool(r["success"]),
            )
            for r in rows
        )
        return cls(path, info, episodes, tuple(rows))

    @property
    def fps(self) -> int:
        return int(self.info["fps"])

    @property
    def features(self) -> dict[str, Any]:
        return dict(self.info["features"])

    @property
    def cameras(self) -> list[str]:
        return [k for k, f in self.features.items() if f["dtype"] == "video"]

    @property
    def total_frames(self) -> int:
        return int(self.info["total_frames"])

    def summary(self) -> dict[str, Any]:
        known = [e.success for e in self.episodes if e.success is not None]
        return {
            "dataset": str(self.root),
            "format": self.info["codebase_version"],
            "robot_type": self.info.get("robot_type"),
            "episodes": len(self.episodes),
            "frames": self.total_frames,
            "fps": self.fps,
            "tasks": sorted({e.task for e in self.episodes}),
            "features": {
                k: f"{f['dtype']} {tuple(f['shape'])}"
                for k, f in self.features.items()
                if k not in INDEX_FEATURES
            },
            "success_rate": (sum(known) / len(known)) if known else math.nan,
        }

    def _episode(self, index: int) -> dict[str, Any]:
        if not 0 <= index < len(self.episodes):
            raise DatasetError(f"episode {index} not in [0, {len(self.episodes) - 1}]")
        return self._episode_rows[index]

    def episode_frames(self, index: int) -> dict[str, np.ndarray]:
        """Every non-video feature of one episode as (T, n) arrays (scalars as (T,))."""
        import pyarrow.parquet as pq

        row = self._episode(index)
        path = self.root / str(self.info["data_path"]).format(
            chunk_index=row["data/chunk_index"], file_index=row["data/file_index"]
        )
        table = pq.read_table(path, filters=[("episode_index", "=", index)])
        table = table.sort_by("frame_index")
        out: dict[str, np.ndarray] = {}
        for name in table.column_names:
            col = table.column(name).combine_chunks()
            if _is_fixed_list(col.type):
                size = col.type.list_size
                out[name] = col.flatten().to_numpy(zero_copy_only=False).reshape(-1, size)
            else:
                out[name] = col.to_numpy(zero_copy_only=False)
        return out

    def video_frames(self, index: int, camera: str) -> Iterator[np.ndarray]:
        """One episode's frames of one camera, decoded with imageio-ffmpeg, in order."""
        import imageio_ffmpeg

        row = self._episode(index)
        if camera not in self.cameras:
            raise DatasetError(f"camera {camera!r} not in {self.cameras}")
        path = self.root / str(self.info["video_path"]).format(
            video_key=camera,
            chunk_index=row[f"videos/{camera}/chunk_index"],
            file_index=row[f"videos/{camera}/file_index"],
        )
        first = round(float(row[f"videos/{camera}/from_timestamp"]) * self.fps)
        h, w = self.features[camera]["shape"][:2]
        reader = imageio_ffmpeg.read_frames(str(path), pix_fmt="rgb24")
        next(reader)  # the metadata dict
        try:
            for i, raw in enumerate(reader):
                if i >= first + row["length"]:
                    break
                if i >= first:
                    yield np.frombuffer(raw, np.uint8).reshape(h, w, 3)
        finally:
            reader.close()


def _is_fixed_list(t: Any) -> bool:
    import pyarrow as pa

    return bool(pa.types.is_fixed_size_list(t))
