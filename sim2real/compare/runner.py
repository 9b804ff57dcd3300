"""``run_compare``: build the (algo, seed) grid, run it on a backend, write the report."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sim2real.errors import ConfigError, RunDirError, UnknownNameError


@dataclass(frozen=True)
class CompareConfig:
    env: str
    algos: tuple[str, ...]
    seeds: int
    steps: int
    out: str
    dr: str = "default"
    backend: str = "local"
    workers: int = 1
    address: str | None = None
    eval_episodes: int = 100
    overrides: Mapping[str, tuple[str, ...]] = field(default_factory=dict)  # algo → KEY=VALUE
    presets: Mapping[str, str] = field(default_factory=dict)  # algo → preset name (else its own)

    def __post_init__(self) -> None:
        import sim2real.envs as envs
        from sim2real.compare.backends import BACKENDS
        from sim2real.randomization import load_preset
        from sim2real.train.algos import get_algo

        object.__setattr__(self, "env", envs.resolve_env_id(self.env))
        if not self.algos:
            raise ConfigError("--algos needs at least one algorithm")
        names = tuple(get_algo(a).name for a in self.algos)
        if len(set(names)) != len(names):
            raise ConfigError(f"--algos lists an algorithm twice: {','.join(names)}")
        object.__setattr__(self, "algos", names)
        for name, value in (
            ("seeds", self.seeds),
            ("steps", self.steps),
            ("workers", self.workers),
            ("eval_episodes", self.eval_episodes),
        ):
            if not isinstance(value, int) or value < 1:
                raise ConfigError(f"{name} must be an integer >= 1, got {value!r}")
        if self.backend not in BACKENDS:
            raise UnknownNameError("backend", self.backend, BACKENDS)
        load_preset(self.dr)
        for flag, given in (("--set", self.overrides), ("--preset", self.presets)):
            unknown = sorted(set(given) - set(names))
            if unknown:
                raise ConfigError(f"{flag} names algorithm(s) {unknown} that are not in --algos")
        from sim2real.train.config import find_preset

        for algo, preset in self.presets.items():
            find_preset(algo, self.env, preset)  # unknown names fail here, before any run


def parse_overrides(items: list[str], algos: tuple[str, ...]) -> dict[str, tuple[str, ...]]:
    """``ALGO:KEY=VALUE`` applies to one algorithm, ``KEY=VALUE`` to all of them."""
    out: dict[str, list[str]] = {}
    for item in items:
        head, sep, rest = item.partition(":")
        if sep and "=" not in head:
            out.setdefault(head.lower(), []).append(rest)
        else:
            for a in algos:
                out.setdefault(a, []).append(item)
    return {k: tuple(v) for k, v in out.items()}


def parse_presets(items: list[str]) -> dict[str, str]:
    """``ALGO:NAME`` per item: the algorithm trains from that preset instead of its own."""
    out: dict[str, str] = {}
    for item in items:
        algo, sep, name = item.partition(":")
        if not sep or not algo or not name:
            raise ConfigError(f"--preset {item!r} must be ALGO:NAME, e.g. ppo:ppo_kuka_fast_asym")
        out[algo.strip().lower()] = name.strip()
    return out


def jobs_for(cfg: CompareConfig) -> list[dict[str, Any]]:
    """Seed-major: every algorithm's seed 0 runs before any seed 1, so a study stopped early
    still compares all of its algorithms."""
    from sim2real.compare.jobs import Job

    runs = Path(cfg.out) / "runs"
    return [
        Job(
            env=cfg.env,
            algo=algo,
            seed=seed,
            steps=cfg.steps,
            dr=cfg.dr,
            run_dir=str(runs / f"{algo}-s{seed}"),
            eval_episodes=cfg.eval_episodes,
            overrides=tuple(cfg.overrides.get(algo, ())),
            preset=cfg.presets.get(algo),
        ).to_dict()
        for seed in range(cfg.seeds)
        for algo in cfg.algos
    ]


def run_compare(cfg: CompareConfig) -> dict[str, Path]:
    from sim2real.compare.backends import BACKENDS
    from sim2real.compare.report import write_report
    from sim2real.train.runner import versions

    out = Path(cfg.out)
    runs = out / "runs"
    if runs.exists() and any(runs.iterdir()):
        raise RunDirError(f"--out {cfg.out!r} already holds runs; choose a new report folder")
    jobs = jobs_for(cfg)
    # Validate every job's config before starting any worker: a typo fails in a second.
    from sim2real.train.config import resolve_config

    for j in jobs:
        resolve_config(
            j["env"],
            j["algo"],
            j["run_dir"],
            dr=j["dr"],
            seed=j["seed"],
            steps=j["steps"],
            overrides=j["overrides"],
            preset=j["preset"],
        )
    results = BACKENDS[cfg.backend](jobs, cfg.workers, cfg.address)
    config = {
        "env_id": cfg.env,
        "algos": list(cfg.algos),
        "seeds": cfg.seeds,
        "steps": cfg.steps,
        "dr": cfg.dr,
        "backend": cfg.backend,
        "workers": cfg.workers,
        "eval_episodes": cfg.eval_episodes,
        "overrides": {k: list(v) for k, v in cfg.overrides.items()},
        "presets": dict(cfg.presets),
    }
    return write_report(out, config, results, versions())
