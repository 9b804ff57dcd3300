"""Where a fine-tune starts (a sim run's SB3 checkpoint) and the run directory it writes.

The source is resolved as ``adapt`` resolves it (``adapt.checkpoint.resolve_source``): a run
directory's newest checkpoint, or a shipped policy's ``<name>.zip`` + ``<name>.train.json``. The
output is a run directory like ``train``'s, so ``evaluate``, ``export`` and ``deploy`` take it::

    OUT/
      config.json        the source's RunMeta: algo, steps and ``adapted_from`` updated
      status.json        RunDir status (steps done, latest checkpoint)
      model.zip          the newest fine-tuned SB3 model (actor, critic, optimisers)
      vecnormalize.pkl   the source's frozen observation statistics
      checkpoints/       step_<N>.zip and step_<N>.replay.npz (online transitions), the newest
      finetune.json      counters (env steps, episodes, arm seconds, learner updates), every
                         episode's figures, the human interventions: what ``--resume`` reads
      episodes/          every episode in the deploy log format (``episode_<N>.npz``)

Every file is written atomically; ``finetune.json`` is written after the checkpoint it names, so
a crash between the two resumes from the previous, complete one.
"""

from __future__ import annotations

import json
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hardware.atomic import atomic_write_bytes, atomic_write_text
from hardware.spec import ArmSpec
from sim2real.errors import ConfigError, RunDirError

STATE_FILE = "finetune.json"
EPISODES_DIR = "episodes"
STATE_FORMAT = 1
# (the source's algorithm, the fine-tune's): the same actor and critic classes, or DDPG's
# checkpoint under TD3's update rule (delayed actor, target smoothing) with its one critic.
ALLOWED: frozenset[tuple[str, str]] = frozenset(
    {("ddpg", "ddpg"), ("td3", "td3"), ("sac", "sac"), ("ddpg", "td3")}
)
ALGOS: tuple[str, ...] = ("ddpg", "td3", "sac")
# what a resume must agree on: anything else would mix two fine-tunes in one buffer
IDENTITY: tuple[str, ...] = ("source", "algo", "backend", "plant", "spec_fingerprint")


@dataclass(frozen=True)
class FinetuneSource:
    """A sim run's checkpoint to fine-tune, and its frozen observation statistics."""

    ref: str
    name: str
    algo: str  # the source's algorithm
    config: dict[str, Any]  # its RunMeta as JSON
    model_zip: Path
    steps: int
    obs_stats: dict[str, Any] | None  # adapt.checkpoint.vecnormalize_stats numbers
    vecnormalize_pkl: Path | None


def check_algo(source_algo: str, algo: str) -> None:
    """One line for an algorithm the fine-tune does not run or a pair it cannot continue."""
    if algo not in ALGOS:
        raise ConfigError(f"--algo {algo!r} is not one of {list(ALGOS)} (off-policy fine-tunes)")
    if source_algo not in ALGOS:
        raise ConfigError(
            f"the source policy was trained with {source_algo!r}: an off-policy fine-tune needs "
            f"a {'/'.join(ALGOS)} checkpoint (actor and critic), not an on-policy one"
        )
    if (source_algo, algo) not in ALLOWED:
        pairs = ", ".join(f"{a}->{b}" for a, b in sorted(ALLOWED))
        raise ConfigError(
            f"--algo {algo} cannot continue a {source_algo} checkpoint (different actor or "
            f"critic); allowed: {pairs}"
        )


def resolve(ref: str, algo: str | None) -> FinetuneSource:
    """The run directory or shipped policy ``ref``, checked against ``algo`` (None: the
    source's own algorithm)."""
    from sim2real.adapt.checkpoint import resolve_source, vecnormalize_stats

    src = resolve_source(ref)
    source_algo = str(src.config.get("algo", "")).lower()
    check_algo(source_algo, algo or source_algo)
    if not src.model_zip.is_file():
        raise RunDirError(f"policy {ref!r}: its checkpoint {src.model_zip.name} is missing")
    stats = src.vecnormalize_stats
    if src.vecnormalize_pkl is not None:
        try:
            with src.vecnormalize_pkl.open("rb") as fh:
                stats = vecnormalize_stats(pickle.load(fh))
        except (OSError, pickle.UnpicklingError, EOFError, AttributeError) as exc:
            raise RunDirError(
                f"policy {ref!r}: unreadable {src.vecnormalize_pkl.name} ({exc})"
            ) from None
    return FinetuneSource(
        ref=ref,
        name=src.name,
        algo=source_algo,
        config=dict(src.config),
        model_zip=src.model_zip,
        steps=src.steps,
        obs_stats=stats,
        vecnormalize_pkl=src.vecnormalize_pkl,
    )


class FinetuneDir:
    """The output folder: a run directory plus the fine-tune's own state."""

    def __init__(self, path: Path) -> None:
        from sim2real.train.rundir import RunDir

        self.path = Path(path)
        self.run = RunDir(self.path)

    @property
    def state_path(self) -> Path:
        return self.path / STATE_FILE

    @property
    def episodes_dir(self) -> Path:
        return self.path / EPISODES_DIR

    def episode_log(self, episode: int) -> Path:
        return self.episodes_dir / f"episode_{episode:05d}.npz"

    def checkpoint_files(self, env_steps: int) -> tuple[Path, Path]:
        ckpt = self.run.checkpoint_paths(env_steps)
        return ckpt.model, ckpt.model.with_name(ckpt.model.stem + ".replay.npz")

    def read_state(self) -> dict[str, Any] | None:
        if not self.state_path.is_file():
            return None
        try:
            data = json.loads(self.state_path.read_text())
        except (OSError, ValueError) as exc:
            raise RunDirError(f"{str(self.state_path)!r} is unreadable ({exc})") from None
        if not isinstance(data, dict) or data.get("format") != STATE_FORMAT:
            raise RunDirError(f"{str(self.state_path)!r} is not a fine-tune state (format 1)")
        return data

    def start(self, identity: dict[str, Any], resume: bool) -> dict[str, Any] | None:
        """The state to continue from (``--resume``), or None for a fresh folder; one line for
        a folder that is not empty without ``--resume``, or whose fine-tune differs."""
        state = self.read_state() if resume else None
        if not resume:
            if self.path.exists() and any(self.path.iterdir()):
                raise ConfigError(
                    f"--out {str(self.path)!r} is not empty: pass --resume to continue the "
                    "fine-tune in it, or choose a new folder"
                )
            return None
        if state is None:
            if self.path.exists() and any(self.path.iterdir()):
                raise RunDirError(
                    f"--resume: {str(self.path)!r} has no {STATE_FILE} (no checkpoint to "
                    "continue from)"
                )
            return None  # nothing written yet: a fresh start
        for key in IDENTITY:
            if state.get(key) != identity.get(key):
                raise ConfigError(
                    f"--resume: {str(self.path)!r} fine-tunes {key} {state.get(key)!r}, not "
                    f"{identity.get(key)!r}"
                )
        ckpt = state.get("checkpoint")
        if not ckpt or not (self.run.checkpoint_dir / ckpt).is_file():
            raise RunDirError(f"--resume: checkpoint {ckpt!r} of {str(self.path)!r} is missing")
        return state

    def write_static(self, src: FinetuneSource, spec: ArmSpec) -> None:
        """The observation statistics, once: frozen on the arm, they never change."""
        from sim2real.adapt.checkpoint import _rebuilt_vecnormalize

        self.episodes_dir.mkdir(parents=True, exist_ok=True)
        self.run.checkpoint_dir.mkdir(parents=True, exist_ok=True)
        target = self.run.vecnormalize_path
        if src.vecnormalize_pkl is not None:
            atomic_write_bytes(target, src.vecnormalize_pkl.read_bytes())
        elif src.obs_stats is not None:
            vn = _rebuilt_vecnormalize(src.config, spec, src.obs_stats)
            atomic_write_bytes(target, pickle.dumps(vn))

    def write_checkpoint_meta(
        self, src: FinetuneSource, algo: str, state: dict[str, Any], backend: str,
        plant: str | None,
    ) -> None:  # fmt: skip
        """After the learner wrote ``state['checkpoint']``: the run's record and status, then
        the fine-tune's state (last: it names the checkpoint a resume loads)."""
        config = json.loads(json.dumps(src.config))
        steps = src.steps + int(state["env_steps"])
        train = dict(config.get("train", {}))
        if "algo" in train:
            train["algo"] = algo
        train.update(steps=steps, run_dir=self.path.name)
        config.update(
            algo=algo,
            steps=steps,
            train=train,
            adapted_from={
                "policy": src.ref,
                "steps": src.steps,
                "algo": src.algo,
                "by": "finetune",
                "backend": backend,
                "plant": plant,
                "env_steps": int(state["env_steps"]),
                "arm_s": float(state["arm_s"]),
            },
        )
        self.run.write_config(config)
        self.run.write_status(
            {
                "steps_done": steps,
                "steps_target": steps,
                "finished": bool(state.get("finished", False)),
                "wall_s": float(state.get("wall_s", 0.0)),
                "segments": int(state.get("segments", 1)),
                "latest_checkpoint": state["checkpoint"],
            }
        )
        atomic_write_text(self.state_path, json.dumps(state, indent=1) + "\n")
        self._prune(state["checkpoint"])

    def _prune(self, keep: str) -> None:
        """Only the newest checkpoint (and its replay) stays: a replay is the arm's data."""
        stem = keep.removesuffix(".zip")
        for p in self.run.checkpoint_dir.iterdir():
            if p.name.startswith("step_") and not p.name.startswith(stem):
                p.unlink(missing_ok=True)
