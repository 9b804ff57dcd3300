"""Runs -> one Rerun recording (``.rrd``), written atomically, and the viewer opened on it.

Scalar series go as whole columns (``rr.send_columns``: one call per series, not per period);
the 3D scene and the frames go period by period. The recording is streamed to a temporary file
beside the target as it is built and moved into place at the end (``s2r_common.atomic``), so a
crash or Ctrl-C never leaves half a recording. A default layout (blueprint) is sent with it: per
run a 3D view, both cameras and the plots; for two runs or more, a first tab with them together.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from hardware.atomic import atomic_write
from hardware.spec import ArmSpec
from sim2real.errors import ConfigError
from sim2real.view.draw import RunDrawer, series
from sim2real.view.scene import ViewCamera
from sim2real.view.signals import signals
from sim2real.view.sources import ViewRun

APPLICATION_ID = "sim2real"


@dataclass
class RunCounts:
    """What went into the recording for one run (the CLI prints it; tests check it)."""

    label: str
    kind: str
    periods: int = 0
    episodes: int = 0
    frames: int = 0  # camera pairs
    markers: int = 0  # marker detections drawn, both cameras
    series: dict[str, int] = field(default_factory=dict)  # entity subpath -> samples
    events: dict[str, int] = field(default_factory=dict)  # overrun, safety rules, stops


def _time_s(run: ViewRun, nominal_s: float) -> np.ndarray:
    t = run.column("t_s")
    if t is not None and np.all(np.isfinite(t)):
        return t - t[0]
    step = nominal_s if np.isfinite(nominal_s) else 1.0
    return np.arange(run.n_periods) * step


def log_run(
    rec: rr.RecordingStream,
    run: ViewRun,
    spec: ArmSpec,
    cameras: tuple[ViewCamera, ViewCamera] | None,
    drain: Any = None,
) -> RunCounts:
    """Everything one run holds, under ``/<run.label>``; ``drain()`` is called now and then."""
    counts = RunCounts(run.label, run.kind, run.n_periods, len(run.episodes))
    drawer = RunDrawer(rec, run.label, spec, run.objects, cameras)
    image_wh = None
    if run.frames is not None:
        h, w = run.frames.image_hw
        image_wh = (w, h)
    sig = signals(run, spec)
    drawer.static({"kind": run.kind, "path": str(run.path), "periods": run.n_periods,
                   **dict(run.notes)}, image_wh)  # fmt: skip
    period = np.arange(run.n_periods)
    time_s = _time_s(run, sig.nominal_period_s)
    for sub, values in series(run.columns, spec.actuator_names, run.objects).items():
        counts.series[sub] = drawer.send_series(sub, values, period, time_s)
    flags = {"overrun": sig.overrun, **{f"safety/{k}": v for k, v in sig.safety.items()}}
    for name, flag in flags.items():
        hits = np.flatnonzero(flag)
        counts.events[name] = len(hits)
        if len(hits):
            drawer.send_series(f"events/{name}", np.ones(len(hits)), hits, time_s[hits])
    texts = [(int(k), f"period {k}: {name.replace('safety/', 'safety: ')}") for name, flag in
             flags.items() for k in np.flatnonzero(flag)]  # fmt: skip
    texts += [(e.period, f"{e.kind}: {e.text}") for e in run.events]
    for e in run.events:
        counts.events[e.kind] = counts.events.get(e.kind, 0) + 1
    for k, text in sorted(texts):
        drawer.set_time(k, float(time_s[k]))
        drawer.event(text)
    ends = [(ep.first_period + ep.periods - 1, ep) for ep in run.episodes]
    known = [(k, ep) for k, ep in ends if ep.success is not None]
    if known:
        idx = np.array([k for k, _ in known])
        ok = np.array([float(bool(ep.success)) for _, ep in known])
        drawer.send_series("outcome/episode_success", ok, idx, time_s[idx])
    for k, ep in ends:
        drawer.set_time(k, float(time_s[k]))
        verdict = "unknown" if ep.success is None else ("success" if ep.success else "failure")
        note = f" ({ep.note})" if ep.note else ""
        level = "INFO" if ep.success is not False else "WARN"
        drawer.event(f"episode {ep.index}: {verdict}{note}, {ep.periods} periods", level)
    keys = list(run.columns)
    for order, ep in enumerate(run.episodes):
        pairs = iter(run.frames.episode_pairs(order)) if run.frames is not None else None
        for k in range(ep.first_period, ep.first_period + ep.periods):
            row = {key: run.columns[key][k] for key in keys}
            drawer.set_time(k, float(time_s[k]))
            drawer.scene(row)
            pair = next(pairs, None) if pairs is not None else None
            if pair is not None:
                counts.markers += drawer.frames(pair, row)
                counts.frames += 1
        if drain is not None:
            drain()
    return counts


def blueprint(labels: Sequence[str], cameras: bool) -> rrb.Blueprint:
    def one(label: str) -> rrb.Container:
        root = f"/{label}"
        left: list[Any] = [rrb.Spatial3DView(origin=f"{root}/world", name=f"{label}: 3D")]
        if cameras:
            left.append(rrb.Horizontal(
                rrb.Spatial2DView(origin=f"{root}/world/cameras/left", name="left camera"),
                rrb.Spatial2DView(origin=f"{root}/world/cameras/right", name="right camera"),
            ))  # fmt: skip
        plots = rrb.Vertical(
            rrb.TimeSeriesView(origin=f"{root}/joints", name="joints (rad)"),
            rrb.TimeSeriesView(origin=f"{root}/timing", name="timing (s)"),
            rrb.TimeSeriesView(origin=root, name="objects, outcome, events",
                               contents=[f"{root}/{s}/**" for s in
                                         ("objects", "gripper", "distance", "outcome", "events")]),
            rrb.TextLogView(origin=f"{root}/events/log", name="events"),
        )  # fmt: skip
        return rrb.Horizontal(rrb.Vertical(*left), plots, name=label)

    tabs = [one(label) for label in labels]
    if len(labels) > 1:
        together = rrb.Horizontal(
            rrb.Spatial3DView(origin="/", name="together: 3D",
                              contents=[f"/{lb}/world/{s}/**" for lb in labels
                                        for s in ("arm", "estimates", "truth")]),
            rrb.TimeSeriesView(origin="/", name="joint readings",
                               contents=[f"/{lb}/joints/*/reading" for lb in labels]),
            name="together",
        )  # fmt: skip
        tabs.insert(0, together)
    return rrb.Blueprint(
        rrb.Tabs(*tabs) if len(tabs) > 1 else tabs[0],
        rrb.BlueprintPanel(expanded=False),  # room for the views; the panels open with a click
        rrb.SelectionPanel(expanded=False),
        rrb.TimePanel(expanded=True),
    )


def write_recording(
    runs: Sequence[ViewRun],
    spec: ArmSpec,
    path: Path,
    cameras: tuple[ViewCamera, ViewCamera] | None = None,
) -> list[RunCounts]:
    """Every run into one ``.rrd`` at ``path`` (atomically); labels must differ."""
    labels = [r.label for r in runs]
    if len(set(labels)) != len(labels):
        raise ConfigError(f"runs need different labels to sit side by side: {labels} (--labels)")
    rec = rr.new_recording(APPLICATION_ID, recording_id=str(uuid.uuid4()))
    stream = rr.binary_stream(recording=rec)
    counts: list[RunCounts] = []

    def write(fh: IO[bytes]) -> None:
        def drain() -> None:
            fh.write(stream.read(flush=True))

        rr.send_blueprint(
            blueprint(labels, cameras is not None or any(r.frames for r in runs)), recording=rec
        )
        for run in runs:
            counts.append(log_run(rec, run, spec, cameras, drain))
        rec.flush(blocking=True)
        drain()
        rr.disconnect(recording=rec)  # ends the stream: its last bytes come after this
        drain()

    try:
        atomic_write(path, write)
    except BaseException:
        rr.disconnect(recording=rec)  # nothing half-written stays; the stream goes quietly
        raise
    return counts


# ---- the viewer ---------------------------------------------------------------------------------
class NoViewerError(ConfigError):
    """There is no screen to open the viewer on."""


def has_display() -> bool:
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def viewer_command(path: Path) -> list[str]:
    """The Rerun viewer that ships in the rerun-sdk wheel, on ``path``."""
    exe = shutil.which("rerun")
    return [exe, str(path)] if exe else [sys.executable, "-m", "rerun", str(path)]


def open_viewer(path: Path) -> subprocess.Popen[bytes]:
    if not has_display():
        raise NoViewerError(
            f"no display to open the viewer on; the recording is {str(path)!r}: copy it to a "
            "machine with one and run `rerun FILE.rrd` there (or use --save FILE.rrd)"
        )
    return subprocess.Popen(viewer_command(path), start_new_session=True)
