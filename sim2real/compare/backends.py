"""Where a comparison's jobs run: local worker processes (default) or Ray tasks.

Both take the same list of job dicts and return the same list of result dicts, in job order, so
the report cannot tell which backend produced it.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from sim2real.compare.jobs import run_job
from sim2real.errors import Sim2RealError, Terminated

JobDict = dict[str, Any]


_worker_interrupted = False  # per worker process: set once a job there was interrupted


def _worker_init() -> None:
    """Ctrl-C raises KeyboardInterrupt in a worker even if it inherited SIGINT ignored, so the
    run it is training leaves a checkpoint (``train`` does that on KeyboardInterrupt)."""
    signal.signal(signal.SIGINT, signal.default_int_handler)


def _run_job_until_interrupted(job: JobDict) -> JobDict:
    """``run_job``, refused once a job in this worker was interrupted: a job the pool had queued
    already must not start training after Ctrl-C."""
    global _worker_interrupted
    if _worker_interrupted:
        raise KeyboardInterrupt("an earlier job in this worker was interrupted")
    try:
        return run_job(job)
    except KeyboardInterrupt:
        _worker_interrupted = True
        raise


def run_local(jobs: Sequence[JobDict], workers: int, address: str | None = None) -> list[JobDict]:
    """A pool of fresh (spawned) processes: torch and MuJoCo state never cross a fork.

    Ctrl-C at a terminal reaches every worker (one process group). SIGTERM (a scheduler,
    ``kill``) reaches only this process, which passes it on as SIGINT, so the runs in flight
    keep their checkpoints either way; no further job starts."""
    if address:
        raise Sim2RealError("--address is for --backend ray; the local backend takes none")
    ctx = mp.get_context("spawn")
    pool = ProcessPoolExecutor(
        max_workers=max(1, workers), mp_context=ctx, initializer=_worker_init
    )
    try:
        return list(pool.map(_run_job_until_interrupted, jobs))
    except KeyboardInterrupt as exc:
        if isinstance(exc, Terminated):
            for child in mp.active_children():
                if child.pid is not None:
                    os.kill(child.pid, signal.SIGINT)
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


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
