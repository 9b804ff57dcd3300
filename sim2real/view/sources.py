"""What ``sim2real view`` reads: one registry of sources, each turning a path into ``ViewRun``s.

Every source speaks the deploy log's vocabulary (``sim2real.deploy.loop.LOG_KEYS``: ``t_s``,
``episode``, ``step``, ``joints_rad``, ``targets_rad``, ``sent_rad``, ``ee_est_m``,
``<name>_est_m``, ``<name>_blind_s``, ``<name>_true_m``, ``true_tool_m``, ``grasped``,
``period_s`` and the section times), plus ``reward`` and ``success`` per period where the run
has them, so one recorder draws them all. A source reads what is there and invents nothing: a
dataset has no commands or truth, a deploy log no reward.

Sources (``SOURCES``, tried in order):

* ``deploy-log``: an ``.npz`` with ``joints_rad`` (``deploy --log``; ``adapt``'s
  ``record/kinematics.npz`` too, whose wrist-marker sightings show as an estimate);
* ``finetune``: a ``finetune`` output folder (``finetune.json`` + ``episodes/*.npz``), with each
  episode's success and the run's stops and human interventions as events;
* ``adapt``: an ``adapt`` output folder: its deploy logs before and after (``zero_shot.npz``,
  ``evaluate.npz``, where written) as two runs, and its kinematic excitation;
* ``dataset``: a LeRobot dataset (``evaluate --record-dataset``, ``deploy --record-dataset``),
  both cameras included.
"""

from __future__ import annotations

import itertools
import json
import re
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from sim2real.errors import ConfigError, UnknownNameError

_LABEL = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


class FrameSource(Protocol):
    """Both cameras' frames of a run, one pair per period, decoded one episode at a time."""

    camera_names: tuple[str, str]
    image_hw: tuple[int, int]

    def episode_pairs(self, order: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """The ``order``-th episode's (left, right) RGB uint8 frames, in period order."""
        ...


@dataclass(frozen=True)
class EpisodeOutcome:
    index: int  # the run's own episode number
    first_period: int  # row of its first period in ``ViewRun.columns``
    periods: int
    success: bool | None  # None: the source does not record it
    note: str = ""


@dataclass(frozen=True)
class RunEvent:
    """Something that happened at a period: a stop, an e-stop, a person's intervention."""

    period: int
    kind: str
    text: str


@dataclass(frozen=True)
class ViewRun:
    """One run as per-period columns (every column the same length) and what is known beside."""

    label: str  # its entity subtree: ``/<label>/...``
    kind: str  # the source that read it
    path: Path
    columns: Mapping[str, np.ndarray]
    objects: tuple[str, ...] = ()  # tracked objects: ``<name>_est_m`` and friends
    episodes: tuple[EpisodeOutcome, ...] = ()
    events: tuple[RunEvent, ...] = ()
    frames: FrameSource | None = None
    rate_hz: float | None = None  # the nominal control rate, where the source says it
    notes: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not _LABEL.match(self.label):
            raise ConfigError(f"run label {self.label!r}: use 1-64 letters, digits, '_' or '-'")
        lengths = {k: len(v) for k, v in self.columns.items()}
        if "joints_rad" not in lengths or len(set(lengths.values())) != 1:
            raise ConfigError(
                f"run {self.label!r}: columns need joints_rad and one length: {lengths}"
            )
        if self.n_periods < 1:
            raise ConfigError(f"run {self.label!r} ({self.path}) has no periods")

    @property
    def n_periods(self) -> int:
        return len(self.columns["joints_rad"])

    def column(self, key: str) -> np.ndarray | None:
        return self.columns.get(key)


@dataclass(frozen=True)
class LoadOptions:
    """What the command line adds to a source: a label, frames recorded beside a log."""

    label: str | None = None
    frames: Path | None = None  # a LeRobot dataset the same deploy recorded (one pair a period)


@dataclass(frozen=True)
class Source:
    name: str
    matches: Callable[[Path], bool]
    load: Callable[[Path, LoadOptions], list[ViewRun]]
    help: str


# ---- helpers ----------------------------------------------------------------------------------
def _label(path: Path, given: str | None) -> str:
    if given is not None:
        return given
    stem = path.stem if path.is_file() else path.name
    return re.sub(r"[^A-Za-z0-9_-]", "_", stem)[:64] or "run"


def _objects(cols: Mapping[str, np.ndarray]) -> tuple[str, ...]:
    """The tracked objects: every ``<name>_est_m`` but the tool's, and not ``goal`` where the
    deploy log keeps it as a copy of the first object's estimate."""
    names = sorted({k[: -len("_est_m")] for k in cols if k.endswith("_est_m")} - {"ee"})
    if "goal" in names and any(
        np.array_equal(cols["goal_est_m"], cols[f"{n}_est_m"], equal_nan=True)
        for n in names
        if n != "goal"
    ):
        names.remove("goal")
    return tuple(names)


def _episodes(columns: Mapping[str, np.ndarray], success: Mapping[int, bool]) -> tuple[
    EpisodeOutcome, ...
]:  # fmt: skip
    ep = np.asarray(columns["episode"], dtype=float).astype(int)
    starts = np.flatnonzero(np.r_[True, ep[1:] != ep[:-1]])
    bounds = [*starts.tolist(), len(ep)]
    return tuple(
        EpisodeOutcome(int(ep[a]), a, b - a, success.get(int(ep[a])))
        for a, b in itertools.pairwise(bounds)
    )


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: np.asarray(data[k]) for k in data.files}
    except (OSError, ValueError) as exc:
        raise ConfigError(f"log {str(path)!r} is not a readable npz file: {exc}") from None


def _log_columns(raw: Mapping[str, np.ndarray], path: Path) -> dict[str, np.ndarray]:
    """A deploy-format log's per-period columns (one length; per-run values left out)."""
    if "joints_rad" not in raw:
        raise ConfigError(f"log {str(path)!r} has no joints_rad column; keys: {sorted(raw)}")
    n = len(raw["joints_rad"])
    cols = {
        k: np.asarray(v, dtype=float) for k, v in raw.items() if np.ndim(v) >= 1 and len(v) == n
    }
    if "episode" not in cols:  # an excitation: one long episode
        cols["episode"] = np.zeros(n)
    if "step" not in cols:
        cols["step"] = np.arange(n, dtype=float)
    if "ee_marker_m" in cols and "wrist_marker_est_m" not in cols:  # adapt's excitation
        cols["wrist_marker_est_m"] = cols.pop("ee_marker_m")
    return cols


# ---- deploy logs ----------------------------------------------------------------------------
def _is_log(path: Path) -> bool:
    return path.is_file() and path.suffix == ".npz"


def _load_log(path: Path, opts: LoadOptions) -> list[ViewRun]:
    cols = _log_columns(_read_npz(path), path)
    episodes = _episodes(cols, {})
    frames = None if opts.frames is None else _paired_frames(opts.frames, episodes)
    if frames is not None:  # the dataset keeps each episode's judged success; the log does not
        verdicts = [e.success for e in frames.dataset.episodes]
        episodes = tuple(replace(e, success=v) for e, v in zip(episodes, verdicts, strict=True))
    return [
        ViewRun(
            label=_label(path, opts.label),
            kind="deploy-log",
            path=path,
            columns=cols,
            objects=_objects(cols),
            episodes=episodes,
            frames=frames,
            notes={"source": "deploy log", "file": str(path)},
        )
    ]


# ---- finetune folders -------------------------------------------------------------------------
def _is_finetune(path: Path) -> bool:
    return path.is_dir() and (path / "finetune.json").is_file() and (path / "episodes").is_dir()


def _load_finetune(path: Path, opts: LoadOptions) -> list[ViewRun]:
    state = json.loads((path / "finetune.json").read_text())
    files = sorted((path / "episodes").glob("episode_*.npz"))
    if not files:
        raise ConfigError(f"finetune folder {str(path)!r} has no episodes/episode_*.npz yet")
    logs = [_log_columns(_read_npz(f), f) for f in files]
    keys = set.intersection(*(set(c) for c in logs))  # a resumed run may have grown a column
    cols = {k: np.concatenate([c[k] for c in logs]) for k in sorted(keys)}
    record = {int(e["episode"]): e for e in state.get("episode_log", [])}
    episodes = _episodes(cols, {k: bool(v["success"]) for k, v in record.items()})
    episodes = tuple(
        EpisodeOutcome(e.index, e.first_period, e.periods, e.success,
                       record.get(e.index, {}).get("kind", ""))
        for e in episodes
    )  # fmt: skip
    first = {e.index: e.first_period for e in episodes}
    events = [
        RunEvent(first.get(int(s.get("episode", -1)), 0), "stop", str(s.get("reason", s)))
        for s in state.get("stops", [])
    ]
    events += [
        RunEvent(first.get(int(i.get("episode", -1)), 0), "intervention", str(i.get("action")))
        for i in state.get("interventions", [])
    ]
    frames = None if opts.frames is None else _paired_frames(opts.frames, episodes)
    return [
        ViewRun(
            label=_label(path, opts.label), kind="finetune", path=path, columns=cols,
            objects=_objects(cols), episodes=episodes,
            events=tuple(sorted(events, key=lambda e: e.period)), frames=frames,
            notes={"source": "finetune folder", "episodes": len(episodes),
                   **{k: state[k] for k in ("env_steps", "arm_s") if k in state}},
        )
    ]  # fmt: skip


# ---- adapt folders ----------------------------------------------------------------------------
# An adapt folder's logs, by the run each is: its deploys before and after, and its excitation.
ADAPT_LOGS: dict[str, tuple[str, ...]] = {
    "before": ("zero_shot.npz", "logs/zero_shot.npz"),
    "after": ("evaluate.npz", "logs/evaluate.npz"),
    "excitation": ("record/kinematics.npz",),
}
ADAPT_FIGURES = {"before": "zero_shot.json", "after": "evaluate.json"}


def _is_adapt(path: Path) -> bool:
    return path.is_dir() and (path / "status.json").is_file() and not _is_finetune(path)


def _load_adapt(path: Path, opts: LoadOptions) -> list[ViewRun]:
    runs = []
    for label, names in ADAPT_LOGS.items():
        found = next((path / n for n in names if (path / n).is_file()), None)
        if found is None:
            continue
        (run,) = _load_log(found, LoadOptions(label=label))
        figures_file = path / ADAPT_FIGURES.get(label, "-")
        notes = dict(run.notes)
        if figures_file.is_file():
            notes["figures"] = json.loads(figures_file.read_text())
        runs.append(_with(run, kind="adapt", notes=notes))
    if not runs:
        wanted = [n for names in ADAPT_LOGS.values() for n in names]
        raise ConfigError(f"adapt folder {str(path)!r} has none of the logs {wanted}")
    return runs


def _with(run: ViewRun, **changes: Any) -> ViewRun:
    return replace(run, **changes)


# ---- LeRobot datasets -------------------------------------------------------------------------
def _is_dataset(path: Path) -> bool:
    return path.is_dir() and (path / "meta" / "info.json").is_file()


class DatasetFrames:
    """A LeRobot dataset's two cameras, decoded from its videos one episode at a time."""

    def __init__(self, dataset: Any, episodes: list[int]) -> None:
        cams = dataset.cameras
        if len(cams) != 2:
            raise ConfigError(f"dataset {str(dataset.root)!r} has cameras {cams}; need two")
        left = next((c for c in cams if "left" in c), cams[0])
        right = next(c for c in cams if c != left)
        self.dataset, self.episodes = dataset, episodes
        self.keys = (left, right)
        self.camera_names = (left.rsplit(".", 1)[-1], right.rsplit(".", 1)[-1])
        h, w = dataset.features[left]["shape"][:2]
        self.image_hw = (int(h), int(w))

    def episode_pairs(self, order: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        ep = self.episodes[order]
        return zip(
            self.dataset.video_frames(ep, self.keys[0]),
            self.dataset.video_frames(ep, self.keys[1]),
            strict=False,
        )


def _open_dataset(path: Path) -> Any:
    from sim2real.datasets.lerobot import LeRobotDataset

    return LeRobotDataset.open(path)


def _paired_frames(path: Path, episodes: tuple[EpisodeOutcome, ...]) -> DatasetFrames:
    """Frames a deploy recorded beside its log (``--record-dataset`` with ``--log``): one pair
    per period, episode for episode, or the pairing is refused."""
    ds = _open_dataset(path)
    if len(ds.episodes) != len(episodes):
        raise ConfigError(
            f"--frames {str(path)!r} has {len(ds.episodes)} episodes, the log {len(episodes)}: "
            "give the dataset the same deploy recorded"
        )
    for mine, theirs in zip(episodes, ds.episodes, strict=True):
        if mine.periods != theirs.length:
            raise ConfigError(
                f"--frames {str(path)!r}: episode {theirs.index} has {theirs.length} frames, the "
                f"log's episode {mine.index} {mine.periods} periods"
            )
    return DatasetFrames(ds, [e.index for e in ds.episodes])


# LeRobot feature -> the deploy log's column
DATASET_COLUMNS: dict[str, str] = {
    "observation.state": "joints_rad",
    "action": "action",
    "observation.tool_pos": "ee_est_m",
    "next.reward": "reward",
    "next.success": "success",
    "next.done": "done",
}


def _load_dataset(path: Path, opts: LoadOptions) -> list[ViewRun]:
    if opts.frames is not None:
        raise ConfigError("--frames pairs a deploy log with its frames; a dataset has its own")
    ds = _open_dataset(path)
    parts: list[dict[str, np.ndarray]] = []
    for ep in ds.episodes:
        raw = ds.episode_frames(ep.index)
        cols: dict[str, np.ndarray] = {}
        for key, value in raw.items():
            name = DATASET_COLUMNS.get(key)
            if name is None and key.startswith("observation.") and key.endswith("_pos"):
                name = key[len("observation.") : -len("_pos")] + "_est_m"
            if name is not None:
                cols[name] = np.asarray(value, dtype=float)
        n = len(raw["frame_index"])
        cols["episode"] = np.full(n, float(ep.index))
        cols["step"] = np.asarray(raw["frame_index"], dtype=float)
        cols["t_s"] = np.asarray(raw["timestamp"], dtype=float)
        parts.append(cols)
    keys = set.intersection(*(set(c) for c in parts))
    columns = {k: np.concatenate([c[k] for c in parts]) for k in sorted(keys)}
    for key in ("reward", "success", "done"):
        if key in columns:
            columns[key] = columns[key].reshape(len(columns[key]), -1)[:, 0]
    # the timestamps restart each episode: one clock over the run, a period apart
    columns["t_s"] = np.arange(len(columns["t_s"])) / ds.fps
    episodes = _episodes(
        columns, {e.index: e.success for e in ds.episodes if e.success is not None}
    )
    frames = DatasetFrames(ds, [e.index for e in ds.episodes]) if len(ds.cameras) == 2 else None
    tasks = sorted({e.task for e in ds.episodes})
    return [
        ViewRun(
            label=_label(path, opts.label), kind="dataset", path=path, columns=columns,
            objects=_objects(columns), episodes=episodes, frames=frames,
            rate_hz=float(ds.fps),
            notes={"source": "LeRobot dataset", "tasks": tasks, "robot_type":
                   ds.info.get("robot_type"), "episodes": len(ds.episodes)},
        )
    ]  # fmt: skip


SOURCES: dict[str, Source] = {
    "deploy-log": Source("deploy-log", _is_log, _load_log, "sim2real deploy --log FILE.npz"),
    "finetune": Source("finetune", _is_finetune, _load_finetune, "sim2real finetune --out DIR"),
    "adapt": Source("adapt", _is_adapt, _load_adapt, "sim2real adapt --out DIR"),
    "dataset": Source("dataset", _is_dataset, _load_dataset, "--record-dataset DIR"),
}


def load_run(path: str | Path, opts: LoadOptions | None = None, kind: str | None = None) -> list[
    ViewRun
]:  # fmt: skip
    """The runs at ``path``, read by the first source that recognises it (or by ``kind``)."""
    p = Path(path)
    opts = opts or LoadOptions()
    if not p.exists():
        raise ConfigError(f"run {str(p)!r} does not exist")
    if kind is not None:
        if kind not in SOURCES:
            raise UnknownNameError("run kind", kind, SOURCES)
        return SOURCES[kind].load(p, opts)
    for source in SOURCES.values():
        if source.matches(p):
            return source.load(p, opts)
    known = "; ".join(f"{s.name} ({s.help})" for s in SOURCES.values())
    raise ConfigError(f"run {str(p)!r} is none of the kinds the viewer reads: {known}")
