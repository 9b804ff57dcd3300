"""A small trained reach policy, trained once and shared (tests, deploy end-to-end checks).

The cache key hashes everything that changes the result (budget, seed, DR, preset text, arm spec,
library versions), so a stale policy is never reused. Concurrent callers (pytest-xdist workers)
serialise on a file lock; the run is trained in a temporary folder and renamed into place, so a
reader sees either nothing or a finished run.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

from sim2real.train.rundir import RunDir

CACHE_ENV_VAR = "SIM2REAL_CACHE"
DEFAULT_CACHE_DIR = ".cache/sim2real/reach-policy"
CACHED_STEPS = 100_000  # ~60-90 s on the 2-core CPU: a policy that reaches, not a tuned one
# The shipped ppo_reach preset trades learning speed for robustness to lag (max_delta 0.05 rad,
# action-rate penalty). A short budget learns faster at the env's default step size.
QUICK_REACH_OVERRIDES: tuple[str, ...] = (
    "env_kwargs.max_delta_rad=0.1",
    "action_rate_penalty=0.0",
)


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as fh:
        try:
            import fcntl
        except ImportError:  # pragma: no cover - Windows: best effort without a lock
            yield
            return
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def _key(steps: int, seed: int, dr: str) -> str:
    from hardware.spec import load_spec
    from sim2real.envs.reach import ReachTask
    from sim2real.train.config import find_preset
    from sim2real.train.runner import versions

    preset = find_preset("ppo", "Sim2Real/Arm3Reach-v0")
    spec = load_spec()
    n_joints = spec.n_joints  # reach: joint readings and actions, no gripper
    blob = json.dumps(
        {
            "steps": steps,
            "seed": seed,
            "dr": dr,
            "preset": preset.read_text(),
            "overrides": QUICK_REACH_OVERRIDES,
            "spec": spec.fingerprint(),
            "obs_layout": [f.name for f in ReachTask().obs_fields(n_joints, n_joints, False)],
            "versions": versions(),
        },
        sort_keys=True,
    )
    return hashlib.sha256(blob.encode()).hexdigest()[:12]


def cached_reach_policy(
    cache_dir: str | Path | None = None,
    steps: int = CACHED_STEPS,
    seed: int = 0,
    dr: str = "default",
) -> Path:
    """Run dir of a PPO policy on Arm3Reach (trained on first use, then reused)."""
    from sim2real.train.config import resolve_config
    from sim2real.train.runner import train

    root = Path(cache_dir or os.environ.get(CACHE_ENV_VAR) or DEFAULT_CACHE_DIR)
    key = _key(steps, seed, dr)
    run = root / f"ppo-reach-{key}"
    if RunDir(run).model_path.is_file():
        return run
    with _locked(root / f"{key}.lock"):
        if RunDir(run).model_path.is_file():  # another worker finished it while we waited
            return run
        tmp = root / f".tmp-{key}-{os.getpid()}"
        shutil.rmtree(tmp, ignore_errors=True)
        cfg = resolve_config(
            "reach",
            "ppo",
            tmp,
            dr=dr,
            seed=seed,
            steps=steps,
            progress=False,
            overrides=[*QUICK_REACH_OVERRIDES, "checkpoint_every=0"],
        )
        train(cfg)
        meta = RunDir(tmp).read_meta()
        RunDir(tmp).write_meta(replace(meta, note="trained by sim2real.train.cached_reach_policy"))
        os.replace(tmp, run)
    return run
