"""Where a comparison's jobs run: local worker processes (default) or Ray tasks.

Both take the same list of job dicts and return the same list of result dicts, in job order, so
the report cannot tell which backend produced it.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from sim2real.compare.jobs import run_job
from sim2real.errors import Sim2RealError

JobDict = dict[str, Any]


def run_local(jobs: Sequence[JobDict], workers: int, address: str | None = None) -> list[JobDict]:
    """A pool of fresh (spawned) processes: torch and MuJoCo state never cross a fork."""
    if address:
        raise Sim2RealError("--address is for --backend ray; the local backend takes none")
    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(max_workers=max(1, workers), mp_context=ctx) as pool:
        return list(pool.map(run_job, jobs))


def run_ray(jobs: Sequence[JobDict], workers: int, address: str | None = None) -> list[JobDict]:
    """Ray tasks, one CPU each: a local Ray with ``workers`` CPUs, or an existing cluster."""
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no telemetry from a lab machine
    try:
        import ray
    except ImportError:  # pragma: no cover - ray is a dependency
        raise Sim2RealError("--backend ray needs the 'ray' package") from None
    started = not ray.is_initialized()
    if started:
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
        if address:
            kwargs["address"] = address
        else:
            kwargs["num_cpus"] = max(1, workers)
        try:
            ray.init(**kwargs)
        except (ConnectionError, ValueError, RuntimeError) as exc:
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise Sim2RealError(
                f"cannot start or reach Ray at {address or 'local'}: {msg}"
            ) from None
    try:
        task = ray.remote(num_cpus=1)(run_job)
        return list(ray.get([task.remote(j) for j in jobs]))
    finally:
        if started:
            ray.shutdown()


BACKENDS: dict[str, Callable[[Sequence[JobDict], int, str | None], list[JobDict]]] = {
    "local": run_local,
    "ray": run_ray,
}
