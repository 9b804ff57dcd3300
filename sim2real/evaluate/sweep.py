"""The transfer-gap report: success over a grid of held-out perturbations.

Each cell pins a few DR keys to single values (for example 2 steps of latency, 0.6x actuator gain,
0.8 px of stereo noise) on top of a base preset, and runs the same held-out seeds in every cell
(common random numbers: differences between cells come from the perturbation, not the draw).
Writes ``sweep.csv`` and ``sweep.png`` (heatmaps of success, one panel per value of the first
axis when there are three).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import product
from pathlib import Path
from typing import Any

from sim2real.errors import ConfigError, UnknownNameError
from sim2real.evaluate.core import EvalTarget
from sim2real.evaluate.rollout import run_episodes
from sim2real.evaluate.stats import wilson_interval
from sim2real.randomization import DRConfig
from sim2real.randomization.config import Range
from sim2real.train.atomic import atomic_write, atomic_write_text


@dataclass(frozen=True)
class SweepAxis:
    """A DR key a sweep can pin: ``category.key`` of the preset, with its unit."""

    category: str
    key: str
    unit: str
    default_values: tuple[float, ...]


SWEEP_AXES: dict[str, SweepAxis] = {
    "latency_steps": SweepAxis("actuation", "latency_steps", "steps", (0, 1, 2, 3)),
    "actuator_gain": SweepAxis("dynamics", "actuator_gain_scale", "x", (0.5, 0.7, 1.0, 1.3)),
    "obs_noise_px": SweepAxis("sensing", "stereo_pixel_noise_px", "px", (0.2, 0.6, 1.0)),
    "obs_delay_steps": SweepAxis("sensing", "obs_delay_steps", "steps", (0, 1, 2)),
    "joint_noise_rad": SweepAxis("sensing", "joint_noise_rad", "rad", (0.0, 0.004, 0.01)),
    "max_speed": SweepAxis("actuation", "max_speed_scale", "x", (0.4, 0.7, 1.0)),
    "deadband_rad": SweepAxis("actuation", "deadband_rad", "rad", (0.004, 0.01, 0.02)),
    "link_mass": SweepAxis("dynamics", "link_mass_scale", "x", (0.8, 1.0, 1.3)),
    "droop_rad": SweepAxis("dynamics", "actuator_droop_rad", "rad", (0.0, 0.01, 0.02, 0.03)),
}
DEFAULT_AXES: tuple[str, ...] = ("latency_steps", "actuator_gain", "obs_noise_px")
MAX_AXES = 3


def parse_axes(specs: Sequence[str]) -> dict[str, tuple[float, ...]]:
    """``["latency_steps=0,1,2", "actuator_gain"]`` → grid (bare names use default values)."""
    grid: dict[str, tuple[float, ...]] = {}
    for spec in specs or DEFAULT_AXES:
        name, sep, raw = spec.partition("=")
        name = name.strip()
        if name not in SWEEP_AXES:
            raise UnknownNameError("sweep axis", name, SWEEP_AXES)
        if name in grid:
            raise ConfigError(f"sweep axis {name!r} given twice")
        if not sep:
            grid[name] = SWEEP_AXES[name].default_values
            continue
        try:
            values = tuple(float(v) for v in raw.split(",") if v.strip())
        except ValueError:
            raise ConfigError(f"sweep axis {spec!r}: values must be numbers") from None
        if not values or not all(math.isfinite(v) for v in values):
            raise ConfigError(f"sweep axis {spec!r}: give finite values, e.g. {name}=0,1,2")
        grid[name] = values
    if len(grid) > MAX_AXES:
        raise ConfigError(f"a sweep takes at most {MAX_AXES} axes, got {list(grid)}")
    return grid


def pinned(base: DRConfig, cell: Mapping[str, float]) -> DRConfig:
    """``base`` with each swept key fixed to one value."""
    ranges: dict[str, dict[str, Range]] = {c: dict(k) for c, k in base.ranges.items()}
    for name, value in cell.items():
        ax = SWEEP_AXES[name]
        ranges[ax.category][ax.key] = Range(float(value), float(value))
    label = ",".join(f"{k}={v:g}" for k, v in cell.items())
    return DRConfig(name=f"{base.name}[{label}]", ranges=ranges)


def run_sweep(
    target: EvalTarget,
    grid: Mapping[str, Sequence[float]],
    episodes: int,
    base_dr: str | None = None,
    seed_offset: int = 0,
    n_parallel: int = 16,
    progress: bool = False,
) -> list[dict[str, Any]]:
    seeds = target.held_out_seeds(episodes, seed_offset)
    base = target.dr(base_dr)
    names = list(grid)
    cells = list(product(*(grid[n] for n in names)))
    rows: list[dict[str, Any]] = []
    from tqdm import tqdm

    from sim2real.progress import progress_enabled

    for values in tqdm(cells, disable=not progress_enabled(progress), unit="cell"):
        cell = dict(zip(names, values, strict=True))
        res = run_episodes(target.policy, target.env_factory(pinned(base, cell)), seeds, n_parallel)
        s = res.summary()
        lo, hi = wilson_interval(res.successes, res.n)
        rows.append(
            {
                **cell,
                "episodes": res.n,
                "success_rate": s["success_rate"],
                "wilson95_low": lo,
                "wilson95_high": hi,
                "mean_final_distance_m": s["mean_final_distance_m"],
                "mean_return": s["mean_return"],
            }
        )
    return rows


def write_csv(rows: Sequence[Mapping[str, Any]], path: str | Path) -> Path:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    return atomic_write_text(path, buf.getvalue())


def _label(name: str) -> str:
    return f"{name} [{SWEEP_AXES[name].unit}]"


def plot_heatmap(
    rows: Sequence[Mapping[str, Any]],
    grid: Mapping[str, Sequence[float]],
    path: str | Path,
    title: str,
) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    names = list(grid)
    lookup = {tuple(r[n] for n in names): r["success_rate"] for r in rows}
    if len(names) == 1:
        fig, ax = plt.subplots(figsize=(5, 3.5))
        xs = list(grid[names[0]])
        ys = [lookup[(x,)] for x in xs]
        err = [
            [y - r["wilson95_low"] for y, r in zip(ys, rows, strict=True)],
            [r["wilson95_high"] - y for y, r in zip(ys, rows, strict=True)],
        ]
        ax.errorbar(xs, ys, yerr=err, marker="o", capsize=3)
        ax.set_xlabel(_label(names[0]))
        ax.set_ylabel("success rate")
        ax.set_ylim(0, 1.05)
    else:
        facets = list(grid[names[0]]) if len(names) == 3 else [None]
        rn, cn = names[-2], names[-1]
        fig, axes = plt.subplots(
            1, len(facets), figsize=(3.6 * len(facets) + 1.2, 3.6), squeeze=False
        )
        im = None
        for ax, f in zip(axes[0], facets, strict=True):
            img = np.array(
                [
                    [lookup[((f,) if f is not None else ()) + (r, c)] for c in grid[cn]]
                    for r in grid[rn]
                ]
            )
            im = ax.imshow(img, vmin=0, vmax=1, cmap="viridis", origin="lower", aspect="auto")
            for (i, j), v in np.ndenumerate(img):
                ax.text(j, i, f"{v:.0%}", ha="center", va="center", color="w" if v < 0.6 else "k")
            ax.set_xticks(range(len(grid[cn])), [f"{v:g}" for v in grid[cn]])
            ax.set_yticks(range(len(grid[rn])), [f"{v:g}" for v in grid[rn]])
            ax.set_xlabel(_label(cn))
            if ax is axes[0][0]:
                ax.set_ylabel(_label(rn))
            if f is not None:
                ax.set_title(f"{names[0]} = {f:g}")
        assert im is not None
        fig.colorbar(im, ax=axes[0].tolist(), label="success rate")
    fig.suptitle(title)
    out = Path(path)

    def _save(fh: Any) -> None:
        fig.savefig(fh, format="png", dpi=110, bbox_inches="tight")

    atomic_write(out, _save)
    plt.close(fig)
    return out
