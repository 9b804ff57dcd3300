"""Where a policy's SB3 checkpoint comes from, and the run directory adapt fine-tunes it in.

A fine-tune is a ``resume`` (``sim2real.train.runner``) of a run directory that adapt writes:
the source's config with the FITTED spec and the centred DR preset, and the source's newest
checkpoint (actor, critic, optimiser; its VecNormalize statistics) as its starting point. So the
fine-tune keeps everything a resume keeps (checkpoints on Ctrl-C, atomic files, a wall-clock
limit), and the exported policy carries the fitted spec's fingerprint like any run.

Sources: a run directory (its newest checkpoint), or a shipped policy whose card names a
``checkpoint`` (``<name>.zip`` plus ``<name>.train.json``: the run's config and the
normalisation statistics as numbers, so no pickle ships in the package).
"""

from __future__ import annotations

import json
import pickle
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hardware.atomic import atomic_write
from hardware.spec import ArmSpec
from sim2real.errors import ConfigError, RunDirError

TRAIN_STATS_FORMAT = 1


@dataclass(frozen=True)
class PolicySource:
    """A policy adapt can fine-tune: its run config and newest checkpoint."""

    name: str  # for the output folder and reports
    ref: str  # what the user passed (deploy takes it as is)
    config: dict[str, Any]  # the run's config.json
    model_zip: Path
    steps: int
    vecnormalize_pkl: Path | None = None  # a run directory's checkpoint
    vecnormalize_stats: dict[str, Any] | None = None  # a shipped policy's numbers
    segments: int = 1  # training segments the source already ran


def resolve_source(ref: str) -> PolicySource:
    """A run directory or a shipped policy name; one-line errors for everything else."""
    from sim2real.policies import shipped
    from sim2real.train.rundir import RunDir

    path = Path(ref)
    if path.is_dir():
        rd = RunDir(path)
        config = rd.read_config()
        ckpt = rd.latest_checkpoint()
        if ckpt is None:
            raise RunDirError(f"run dir {ref!r} has no checkpoint to fine-tune from")
        return PolicySource(
            name=path.resolve().name,
            ref=ref,
            config=config,
            model_zip=ckpt.model,
            steps=ckpt.steps,
            vecnormalize_pkl=ckpt.vecnormalize
            if ckpt.vecnormalize and ckpt.vecnormalize.is_file()
            else None,
            segments=max(1, int(rd.read_status().get("segments", 1))),
        )
    if path.exists():
        raise ConfigError(
            f"policy {ref!r} is an exported file: adapt fine-tunes an SB3 checkpoint; pass its "
            "run directory or a shipped policy name"
        )
    ships = shipped()
    if ref not in ships:
        raise RunDirError(
            f"policy {ref!r} does not exist: no run directory or shipped policy of that name; "
            f"shipped policies: {sorted(ships) or 'none'}"
        )
    pol = ships[ref]
    if pol.checkpoint is None:
        with_ckpt = sorted(n for n, p in ships.items() if p.checkpoint is not None)
        raise ConfigError(
            f"shipped policy {ref!r} carries no SB3 checkpoint, so adapt cannot fine-tune it; "
            f"pass its run directory, or one of {with_ckpt or 'none'}"
        )
    model_zip, stats_path = pol.checkpoint
    try:
        stats = json.loads(stats_path.read_text())
        config = dict(stats["config"])
        steps = int(stats["steps"])
        segments = int(stats.get("segments", 1))
        vn = stats.get("vecnormalize")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise RunDirError(f"shipped policy {ref!r}: unreadable {stats_path.name} ({exc})") from None
    return PolicySource(
        name=ref,
        ref=ref,
        config=config,
        model_zip=model_zip,
        steps=steps,
        vecnormalize_stats=vn,
        segments=max(1, segments),
    )


def vecnormalize_stats(vn: Any) -> dict[str, Any]:
    """The numbers of a VecNormalize (observation and return running statistics, clips)."""
    if vn.norm_obs_keys or isinstance(vn.obs_rms, dict):
        raise ConfigError("shipping a checkpoint with dict observations is not supported")
    return {
        "norm_obs": bool(vn.norm_obs),
        "norm_reward": bool(vn.norm_reward),
        "clip_obs": float(vn.clip_obs),
        "clip_reward": float(vn.clip_reward),
        "gamma": float(vn.gamma),
        "epsilon": float(vn.epsilon),
        "obs_mean": [float(v) for v in vn.obs_rms.mean],
        "obs_var": [float(v) for v in vn.obs_rms.var],
        "obs_count": float(vn.obs_rms.count),
        "ret_mean": float(vn.ret_rms.mean),
        "ret_var": float(vn.ret_rms.var),
        "ret_count": float(vn.ret_rms.count),
    }


def _no_machine_paths(config: dict[str, Any]) -> dict[str, Any]:
    """The config with every absolute path (run dir, spec or DR file) cut to its last part: a
    shipped file must not carry the shipping machine's paths, and a fine-tune replaces them."""

    def scrub(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: scrub(v) for k, v in value.items()}
        if isinstance(value, list):
            return [scrub(v) for v in value]
        if isinstance(value, str) and Path(value).is_absolute():
            return Path(value).name
        return value

    return dict(scrub(config))


def train_stats_text(config: dict[str, Any], steps: int, segments: int, vn: Any | None) -> str:
    """``<name>.train.json`` of a shipped policy: what a fine-tune needs beside the .zip."""
    body = {
        "format": TRAIN_STATS_FORMAT,
        "steps": int(steps),
        "segments": int(segments),
        "config": _no_machine_paths(config),
        "vecnormalize": None if vn is None else vecnormalize_stats(vn),
    }
    return json.dumps(body, indent=1) + "\n"


def _rebuilt_vecnormalize(config: dict[str, Any], spec: ArmSpec, stats: dict[str, Any]) -> Any:
    """A VecNormalize with the shipped statistics, around one env of the run (so its spaces are
    the ones ``set_venv`` checks on resume)."""
    import numpy as np
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    import sim2real.envs as envs

    kwargs = {**dict(config.get("env_kwargs", {})), "spec": spec}
    venv = DummyVecEnv([lambda: envs.make(str(config["env_id"]), **kwargs)])
    try:
        vn = VecNormalize(
            venv,
            norm_obs=bool(stats["norm_obs"]),
            norm_reward=bool(stats["norm_reward"]),
            clip_obs=float(stats["clip_obs"]),
            clip_reward=float(stats["clip_reward"]),
            gamma=float(stats["gamma"]),
            epsilon=float(stats["epsilon"]),
        )
        mean = np.asarray(stats["obs_mean"], dtype=np.float64)
        obs_rms: Any = vn.obs_rms  # a RunningMeanStd: the env's observations are one Box
        if obs_rms.mean.shape != mean.shape:
            raise RunDirError(
                f"shipped statistics have {mean.shape} observations, the env {obs_rms.mean.shape}"
            )
        obs_rms.mean = mean
        obs_rms.var = np.asarray(stats["obs_var"], dtype=np.float64)
        obs_rms.count = float(stats["obs_count"])
        ret_rms: Any = vn.ret_rms
        ret_rms.mean = np.float64(stats["ret_mean"])
        ret_rms.var = np.float64(stats["ret_var"])
        ret_rms.count = float(stats["ret_count"])
    finally:
        venv.close()
    return vn


def prepare_finetune_dir(
    src: PolicySource,
    run_dir: Path,
    spec: ArmSpec,
    dr_path: Path,
    dr_ranges: dict[str, Any],
    max_steps: int,
    wall_s: float,
) -> None:
    """Write the fine-tune run directory: config (fitted spec, centred DR, budget), the source's
    checkpoint as ``checkpoints/step_N``, status. Files are written atomically, the status last:
    a folder interrupted here has no status and is rebuilt on the next run."""
    from sim2real.train.rundir import RunDir

    rd = RunDir(run_dir)
    if rd.path.exists():
        shutil.rmtree(rd.path)
    rd.checkpoint_dir.mkdir(parents=True)
    config = json.loads(json.dumps(src.config))  # a deep copy
    train = dict(config.get("train", {}))
    train.update(
        steps=src.steps + int(max_steps),
        max_wall_s=float(wall_s),
        run_dir=str(run_dir),
        progress=False,
        spec_path=None,
        dr=str(dr_path),  # TrainConfig takes a preset name or a YAML path
    )
    config.update(
        spec=spec.to_dict(),
        spec_name=spec.name,
        spec_fingerprint=spec.fingerprint(),
        dr="adapt",
        dr_source=str(dr_path),
        dr_ranges=dr_ranges,
        steps=train["steps"],
        train=train,
        adapted_from={
            "policy": src.ref,
            "steps": src.steps,
            "spec_name": src.config.get("spec_name"),
            "spec_fingerprint": src.config.get("spec_fingerprint"),
        },
    )
    ckpt = rd.checkpoint_paths(src.steps)
    atomic_write(ckpt.model, lambda fh: fh.write(src.model_zip.read_bytes()))
    if src.vecnormalize_pkl is not None and ckpt.vecnormalize is not None:
        data = src.vecnormalize_pkl.read_bytes()
        atomic_write(ckpt.vecnormalize, lambda fh: fh.write(data))
    elif src.vecnormalize_stats is not None and ckpt.vecnormalize is not None:
        vn = _rebuilt_vecnormalize(config, spec, src.vecnormalize_stats)
        atomic_write(ckpt.vecnormalize, lambda fh: pickle.dump(vn, fh))
    rd.write_config(config)
    status = {
        "steps_done": src.steps,
        "steps_target": train["steps"],
        "finished": False,
        "wall_s": 0.0,
        "segments": src.segments,  # fresh env seeds: the source's next segment
        "latest_checkpoint": ckpt.model.name,
    }
    rd.write_status(status)
