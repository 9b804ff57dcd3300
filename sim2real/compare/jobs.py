"""One (algo, seed) job of a comparison: train, evaluate on held-out seeds, collect curves.

``run_job`` takes and returns plain dicts so any backend (a process pool, Ray) can ship it.
"""

from __future__ import annotations

import csv
import json
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Job:
    env: str
    algo: str
    seed: int
    steps: int
    dr: str
    run_dir: str
    eval_episodes: int
    overrides: tuple[str, ...] = ()
    preset: str | None = None  # None: the algorithm's own preset for the env
    n_bins: int = 30
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _bin(t: np.ndarray, v: np.ndarray, edges: np.ndarray) -> list[float | None]:
    """Mean of ``v`` per timestep bin (None where a bin is empty)."""
    idx = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, len(edges) - 2)
    out: list[float | None] = []
    for b in range(len(edges) - 1):
        sel = v[(idx == b) & np.isfinite(v)]
        out.append(float(sel.mean()) if len(sel) else None)
    return out


def read_episodes(path: Path) -> dict[str, np.ndarray]:
    cols: dict[str, list[float]] = {"timesteps": [], "return": [], "length": [], "is_success": []}
    if path.is_file():
        with path.open(newline="") as fh:
            for row in csv.DictReader(fh):
                for k in cols:
                    cols[k].append(float(row[k]))
    return {k: np.asarray(v, dtype=float) for k, v in cols.items()}


def read_metrics(path: Path, keys: Sequence[str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    rows: dict[str, tuple[list[float], list[float]]] = {k: ([], []) for k in keys}
    if path.is_file():
        for line in path.read_text().splitlines():
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:  # a line cut by a crash: skip it
                continue
            for k in keys:
                if k in rec and math.isfinite(rec[k]):
                    rows[k][0].append(rec["timesteps"])
                    rows[k][1].append(rec[k])
    return {k: (np.asarray(t), np.asarray(v)) for k, (t, v) in rows.items()}


def curves(run_dir: Path, algo: str, steps: int, n_bins: int) -> dict[str, Any]:
    """Training curves binned on a shared timestep grid, so seeds can be averaged bin by bin."""
    from sim2real.train.algos import get_algo
    from sim2real.train.rundir import RunDir

    rd = RunDir(run_dir)
    edges = np.linspace(0, steps, n_bins + 1)
    ep = read_episodes(rd.episodes_path)
    learning = {
        name: _bin(ep["timesteps"], ep[col], edges)
        for name, col in (
            ("success_rate", "is_success"),
            ("return", "return"),
            ("length", "length"),
        )
    }
    diag_keys = get_algo(algo).diagnostics
    metrics = read_metrics(rd.metrics_path, diag_keys)
    diagnostics = {k: _bin(t, v, edges) for k, (t, v) in metrics.items()}
    return {
        "bin_centres": ((edges[:-1] + edges[1:]) / 2).tolist(),
        "learning": learning,
        "diagnostics": diagnostics,
        "train_episodes": len(ep["timesteps"]),
    }


def run_job(job: Mapping[str, Any]) -> dict[str, Any]:
    """Train + evaluate one (algo, seed); returns a JSON-able record."""
    import torch

    torch.set_num_threads(1)
    from sim2real.evaluate import EvalTarget, evaluate
    from sim2real.train import resolve_config, train

    j = Job(**{**job, "overrides": tuple(job.get("overrides", ()))})
    cfg = resolve_config(
        j.env,
        j.algo,
        j.run_dir,
        dr=j.dr,
        seed=j.seed,
        steps=j.steps,
        overrides=j.overrides,
        preset=j.preset,
        progress=False,
    )
    t0 = time.perf_counter()
    result = train(cfg)
    wall_s = time.perf_counter() - t0
    target = EvalTarget.load(j.run_dir)
    ev = evaluate(target, j.eval_episodes)
    return {
        "algo": j.algo,
        "seed": j.seed,
        "run_dir": j.run_dir,
        "steps": result.steps_done,
        "wall_s": wall_s,
        "steps_per_s": result.steps_per_s,
        "train_success_rate": result.train_success_rate,
        "eval": ev,
        "curves": curves(Path(j.run_dir), j.algo, j.steps, j.n_bins),
    }
