"""``sim2real view RUN [RUN ...]``: a run in Rerun (``sim2real.view``): the arm, its commands,
what the cameras saw, timing and safety events; two runs side by side.

Without ``--save`` the recording goes to a temporary file and the viewer opens on it; ``--save
FILE.rrd`` only writes it (a headless machine: open it elsewhere with ``rerun FILE.rrd``).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sim2real.errors import ConfigError

if TYPE_CHECKING:
    from sim2real.view.sources import ViewRun


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "runs", nargs="+", metavar="RUN",
        help="a deploy log (.npz), a finetune or adapt folder, or a LeRobot dataset folder; "
        "two or more sit side by side",
    )  # fmt: skip
    parser.add_argument("--save", type=Path, default=None, metavar="FILE.rrd",
                        help="write the recording here and open no viewer")  # fmt: skip
    parser.add_argument("--labels", default=None, help="comma-separated names, one per RUN")
    parser.add_argument(
        "--frames", action="append", default=[], metavar="DIR",
        help="a deploy log's camera frames: the dataset the same deploy wrote with "
        "--record-dataset (once per RUN, in order; '-' for none)",
    )  # fmt: skip
    parser.add_argument("--kind", default=None, help="read RUN as this kind (default: detected)")
    parser.add_argument("--spec", default=None, help="ArmSpec YAML the run used (default: shipped)")
    parser.add_argument("--calibration", type=Path, default=None,
                        help="a real rig's stereo calibration (default: the mock rig's cameras)")  # fmt: skip
    parser.add_argument("--registration", type=Path, default=None,
                        help="a real rig's base_T_cam file (with --calibration)")  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print what was recorded as JSON")


def _per_run(text: str | None, values: list[str], n: int, what: str) -> list[str | None]:
    items: list[str | None] = [None] * n
    given = values if text is None else text.split(",")
    if not given:
        return items
    if len(given) != n:
        raise ConfigError(f"{what}: {len(given)} given for {n} runs ({given}); give one per RUN")
    return [None if g in ("-", "") else g for g in given]


def _cameras(args: argparse.Namespace) -> Any:
    from sim2real.view.scene import calibrated_cameras, mock_rig_cameras

    if (args.calibration is None) != (args.registration is None):
        raise ConfigError("--calibration and --registration go together (a real rig's cameras)")
    if args.calibration is not None:
        return calibrated_cameras(args.calibration, args.registration)
    try:
        return mock_rig_cameras()
    except ImportError:  # no MuJoCo: frames still show, without the rig's overlays
        return None


def run(args: argparse.Namespace) -> int:
    import rerun  # noqa: F401  # first: without the 'view' extra, say so before reading anything

    from hardware.spec import load_spec
    from sim2real.view.record import has_display, open_viewer, write_recording
    from sim2real.view.sources import LoadOptions, load_run

    if args.save is None and not has_display():
        raise ConfigError(
            "no display to open the viewer on: write the recording with --save FILE.rrd and "
            "open it where there is one (rerun FILE.rrd)"
        )
    if args.save is not None and args.save.suffix != ".rrd":
        raise ConfigError(f"--save {str(args.save)!r}: a Rerun recording ends in .rrd")
    labels = _per_run(args.labels, [], len(args.runs), "--labels")
    frames = _per_run(None, args.frames, len(args.runs), "--frames")
    runs = []
    for path, label, frame_dir in zip(args.runs, labels, frames, strict=True):
        found = load_run(
            path, LoadOptions(None, None if frame_dir is None else Path(frame_dir)), args.kind
        )
        if label is not None:  # one run: its label; several (adapt): the label as their prefix
            found = [_relabel(r, label if len(found) == 1 else f"{label}-{r.label}") for r in found]
        runs.extend(found)
    spec = load_spec(args.spec)
    cameras = _cameras(args)
    out = args.save or Path(tempfile.mkdtemp(prefix="sim2real-view-")) / "view.rrd"
    counts = write_recording(runs, spec, out, cameras)
    summary: dict[str, Any] = {
        "recording": str(out),
        "runs": [
            {"label": c.label, "kind": c.kind, "periods": c.periods, "episodes": c.episodes,
             "frames": c.frames, "markers": c.markers, "events": c.events}
            for c in counts
        ],
    }  # fmt: skip
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"recording  {out}")
        for c in summary["runs"]:
            events = ", ".join(f"{k} {v}" for k, v in c["events"].items() if v) or "none"
            print(f"  {c['label']:12s} {c['kind']:10s} periods {c['periods']:5d}  episodes "
                  f"{c['episodes']:3d}  frames {c['frames']:5d}  markers {c['markers']:5d}  "
                  f"events: {events}")  # fmt: skip
    if args.save is None:
        open_viewer(out)
    return 0


def _relabel(run: ViewRun, label: str) -> ViewRun:
    from dataclasses import replace

    return replace(run, label=label)
