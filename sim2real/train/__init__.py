"""Training: SB3 algorithms through one registry, presets per (algo, env), run directories.

Public API (imported lazily, so ``sim2real.train.rundir`` stays light for the robot side)::

    cfg = resolve_config("reach", "ppo", "runs/reach-ppo", dr="default", seed=0)
    result = train(cfg)            # or resume("runs/reach-ppo")
    run = cached_reach_policy()    # a small trained reach run shared by tests and demos
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sim2real.runmeta import RunMeta
    from sim2real.train.algos import ALGOS, AlgoSpec, get_algo
    from sim2real.train.cache import cached_reach_policy
    from sim2real.train.config import TrainConfig, resolve_config
    from sim2real.train.rundir import RunDir
    from sim2real.train.runner import TrainResult, resume, train

_LAZY: dict[str, str] = {
    "ALGOS": "sim2real.train.algos",
    "AlgoSpec": "sim2real.train.algos",
    "get_algo": "sim2real.train.algos",
    "cached_reach_policy": "sim2real.train.cache",
    "TrainConfig": "sim2real.train.config",
    "resolve_config": "sim2real.train.config",
    "RunDir": "sim2real.train.rundir",
    "RunMeta": "sim2real.runmeta",
    "TrainResult": "sim2real.train.runner",
    "resume": "sim2real.train.runner",
    "train": "sim2real.train.runner",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'sim2real.train' has no attribute {name!r}")


__all__ = [
    "ALGOS",
    "AlgoSpec",
    "RunDir",
    "RunMeta",
    "TrainConfig",
    "TrainResult",
    "cached_reach_policy",
    "get_algo",
    "resolve_config",
    "resume",
    "train",
]
