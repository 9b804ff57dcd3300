"""``train`` and ``resume``: a run directory in, a trained SB3 model (and its records) out.

A run is one or more *segments*: the first trains from scratch, each ``resume`` continues from the
newest checkpoint with fresh env seeds (recorded, so evaluation can prove its seeds are held out).
"""

from __future__ import annotations

import contextlib
import copy
import datetime as dt
import importlib.metadata
import io
import pickle
import platform
import shutil
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, cast

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.logger import Logger, TensorBoardOutputFormat
from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise
from stable_baselines3.common.preprocessing import is_image_space
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from hardware.spec import ArmSpec, load_spec
from sim2real.errors import ConfigError, RunDirError
from sim2real.randomization import DRConfig, load_preset
from sim2real.runmeta import ObsField, RunMeta
from sim2real.train.algos import ACTIVATIONS, AlgoSpec, get_algo
from sim2real.train.asymmetric import AsymmetricActorCriticPolicy
from sim2real.train.atomic import atomic_write
from sim2real.train.callbacks import (
    EpisodeLog,
    JsonlMetrics,
    ProgressBar,
    RunDirCheckpoint,
    WallClockLimit,
    save_checkpoint,
)
from sim2real.train.config import (
    EVAL_SEED_BASE,
    SCHEDULABLE,
    SCHEDULE_PREFIX,
    TrainConfig,
    check_action_space,
)
from sim2real.train.extractors import resolve_policy_kwargs
from sim2real.train.factory import build_vec_env, obs_normalization, policy_for, transpose_images
from sim2real.train.rundir import Checkpoint, RunDir
from sim2real.train.wrappers import delta_action_table

VERSION_PACKAGES: tuple[str, ...] = (
    "sim2real",
    "numpy",
    "torch",
    "stable-baselines3",
    "gymnasium",
    "mujoco",
)


# The torch device SB3 trains on. CPU unless this is set (e.g. ``cuda``): every figure in
# BENCHMARKS.md is a CPU figure unless it says otherwise, and a saved model loads on the CPU.
TORCH_DEVICE_ENV = "SIM2REAL_TORCH_DEVICE"


def torch_device() -> str:
    """``$SIM2REAL_TORCH_DEVICE`` (default ``cpu``), checked before anything is built."""
    import os

    name = os.environ.get(TORCH_DEVICE_ENV, "") or "cpu"
    try:
        device = th.device(name)
    except RuntimeError:
        raise ConfigError(f"{TORCH_DEVICE_ENV}={name!r} is not a torch device") from None
    if device.type == "cuda" and not th.cuda.is_available():
        raise ConfigError(f"{TORCH_DEVICE_ENV}={name!r}, but torch sees no CUDA device")
    return name


@dataclass(frozen=True)
class TrainResult:
    run_dir: Path
    steps_done: int
    wall_s: float
    steps_per_s: float  # this segment's env steps per wall second, updates included
    train_success_rate: float | None  # SB3's window of recent training episodes
    stopped_by_wall_limit: bool = False


def versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in VERSION_PACKAGES:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:  # pragma: no cover
            out[name] = "not installed"
    return out


def _segment_seeds(seed: int, n_envs: int, segment: int) -> list[int]:
    """Consecutive reset seeds of segment ``segment``; all stay below the evaluation range."""
    base = seed + segment * 1_000_003
    seeds = list(range(base, base + n_envs))
    if seeds[-1] >= EVAL_SEED_BASE:
        raise ConfigError(f"seed {seed} with {segment} resumes runs into the evaluation seeds")
    return seeds


def _action_table(cfg: TrainConfig, algo: AlgoSpec, env: gym.Env[Any, Any]) -> np.ndarray | None:
    """The joint-delta table a discrete-only algo needs on a ``Box`` env, sized from the env's
    own action space (a gripper, when the task has one, is its last dimension); ``None`` for an
    algo that acts in the ``Box`` itself or an env whose own actions are ``Discrete``."""
    space = env.action_space
    if not algo.discrete_actions or isinstance(space, gym.spaces.Discrete):
        return None
    if not isinstance(space, gym.spaces.Box) or len(space.shape) != 1:
        raise ConfigError(f"{algo.name} cannot act in {cfg.env_id}'s action space {space}")
    task = getattr(env.unwrapped, "task", None)
    gripper = bool(getattr(task, "uses_gripper", False))
    return delta_action_table(
        space.shape[0] - int(gripper), cfg.discrete_magnitudes, gripper=gripper
    )


def _check_observation_features(cfg: TrainConfig, env: gym.Env[Any, Any]) -> None:
    """Augmentation needs an image; an asymmetric critic or a teacher the privileged state."""
    space = env.observation_space
    parts = space.spaces.values() if isinstance(space, gym.spaces.Dict) else (space,)
    if cfg.augment and not any(is_image_space(s) for s in parts):
        raise ConfigError(f"augment: {cfg.env_id} does not observe an image")
    if cfg.uses_privileged and getattr(env.unwrapped, "privileged_space", None) is None:
        what = "privileged_critic" if cfg.privileged_critic else f"algo {cfg.algo}"
        raise ConfigError(f"{what}: {cfg.env_id} reports no privileged state")


def _env_kwargs(cfg: TrainConfig, dr: DRConfig, spec: ArmSpec) -> dict[str, Any]:
    return {**dict(cfg.env_kwargs), "dr": dr, "spec": spec}


def _obs_description(env: gym.Env[Any, Any]) -> dict[str, Any]:
    """The observation contract and action decoding the deploy loop must reproduce (``RunMeta``
    fields)."""
    base = env.unwrapped
    layout = tuple(
        ObsField(f.name, f.start, f.stop, f.unit, f.doc)
        for f in base.builder.layout()  # type: ignore[attr-defined]
    )
    space = env.observation_space
    actions = base.action_space
    discrete = isinstance(actions, gym.spaces.Discrete)
    keys = sizes = shapes = None
    shape = tuple(int(n) for n in space.shape or ())
    if isinstance(space, gym.spaces.Dict):  # policies see the keys flattened in sorted order
        keys = tuple(space.spaces)
        shapes = tuple(tuple(int(n) for n in space.spaces[k].shape or ()) for k in keys)
        sizes = tuple(int(np.prod(s)) for s in shapes)
        shape = (sum(sizes),)
    task = getattr(base, "task", None)
    return {
        "task": str(getattr(task, "name", "")),
        "obs_layout": layout,
        "obs_mode": str(base.obs_mode),  # type: ignore[attr-defined]
        "obs_shape": shape,
        "obs_keys": keys,
        "obs_key_sizes": sizes,
        **({} if shapes is None else {"obs_key_shapes": shapes}),
        # A Discrete env's policy outputs one index; a Box env's policy one value per dimension.
        "action_dim": 1 if discrete else int(np.prod(actions.shape or (1,))),
        "n_actions": int(actions.n) if discrete else None,  # type: ignore[attr-defined]
        "control_hz": 1.0 / base.control_dt_s,  # type: ignore[attr-defined]
        "max_delta_rad": float(base.decoder.max_delta_rad),  # type: ignore[attr-defined]
    }


class LinearSchedule:
    """``lin_<v>`` in a preset: ``v`` at the start, decaying linearly to 0 at the last step
    (SB3 passes the remaining progress, 1 → 0). A class, not a lambda, so checkpoints pickle it."""

    def __init__(self, start: float) -> None:
        self.start = start

    def __call__(self, progress_remaining: float) -> float:
        # SB3 overshoots the budget by up to one rollout: never a negative learning rate
        return max(progress_remaining, 0.0) * self.start


def _schedule(value: Any) -> Any:
    if isinstance(value, str) and value.startswith(SCHEDULE_PREFIX):
        return LinearSchedule(float(value.removeprefix(SCHEDULE_PREFIX)))
    return value


def _hyperparams(cfg: TrainConfig, algo: AlgoSpec, n_actions: int) -> dict[str, Any]:
    hp = copy.deepcopy(dict(cfg.hyperparams))
    for key in SCHEDULABLE:
        if key in hp:
            hp[key] = _schedule(hp[key])
    pk = dict(hp.get("policy_kwargs") or {})
    if "activation_fn" in pk:
        pk["activation_fn"] = ACTIVATIONS[pk["activation_fn"]]
    shift_px = int((cfg.augment or {}).get("random_shift_px", 0))
    pk = resolve_policy_kwargs(pk, shift_px, pixel_actor=cfg.uses_privileged)
    if pk:
        hp["policy_kwargs"] = pk
    if cfg.action_noise is not None:
        sigma = float(cfg.action_noise.get("sigma", 0.1))
        mean, sig = np.zeros(n_actions), sigma * np.ones(n_actions)
        noise_cls = (
            NormalActionNoise
            if cfg.action_noise["type"] == "normal"
            else OrnsteinUhlenbeckActionNoise
        )
        hp["action_noise"] = noise_cls(mean=mean, sigma=sig)
    if cfg.her:
        from stable_baselines3 import HerReplayBuffer

        hp["replay_buffer_class"] = HerReplayBuffer
        hp["replay_buffer_kwargs"] = {**dict(cfg.her_kwargs), **hp.get("replay_buffer_kwargs", {})}
    return hp


def _logger(rd: RunDir, tensorboard: bool = True) -> Logger:
    outputs: list[Any] = [JsonlMetrics(rd.metrics_path)]
    if tensorboard:
        rd.tb_dir.mkdir(parents=True, exist_ok=True)
        outputs.append(TensorBoardOutputFormat(str(rd.tb_dir)))
    return Logger(folder=None, output_formats=outputs)


class _Session:
    """One training segment: envs, model, callbacks, and the status bookkeeping."""

    def __init__(self, cfg: TrainConfig, rd: RunDir, spec: ArmSpec, dr: DRConfig) -> None:
        import sim2real.envs as envs

        self.cfg, self.rd, self.spec, self.dr = cfg, rd, spec, dr
        self.algo = get_algo(cfg.algo)
        probe = envs.make(cfg.env_id, **_env_kwargs(cfg, dr, spec))  # the spaces, as built
        try:
            discrete = isinstance(probe.action_space, gym.spaces.Discrete)
            check_action_space(self.algo.name, cfg.env_id, discrete)
            self.table = _action_table(cfg, self.algo, probe)
            self.obs_desc = _obs_description(probe)
            _check_observation_features(cfg, probe)
        finally:
            probe.close()
        self.status = rd.read_status()
        self.segment = int(self.status.get("segments", 0))
        self.seeds = _segment_seeds(cfg.seed, cfg.n_envs, self.segment)
        self.wall_before_s = float(self.status.get("wall_s", 0.0))
        self._t0 = time.perf_counter()

    def vec_env(self, vecnormalize: Path | None) -> VecEnv:
        """The training envs; a ``VecNormalize`` only when it normalises something."""
        self.rd.monitor_dir.mkdir(parents=True, exist_ok=True)
        venv: VecEnv = transpose_images(
            build_vec_env(
                self.cfg.env_id,
                _env_kwargs(self.cfg, self.dr, self.spec),
                self.seeds,
                self.cfg.vec_env,
                self.table,
                str(self.rd.monitor_dir / f"seg{self.segment}"),
                self.cfg.action_rate_penalty,
                self.cfg.start_curriculum,
                self.cfg.uses_privileged,
            )
        )
        if vecnormalize is not None:
            with vecnormalize.open("rb") as fh:
                saved: VecNormalize = pickle.load(fh)
            if not (saved.norm_obs or saved.norm_reward):  # older pixel runs saved a no-op one
                return venv
            saved.set_venv(venv)
            saved.training = True
            return saved
        norm_obs, keys = obs_normalization(venv.observation_space, self.cfg.normalize)
        if norm_obs or self.cfg.normalize_reward:
            venv = VecNormalize(
                venv,
                norm_obs=norm_obs,
                norm_obs_keys=keys,
                norm_reward=self.cfg.normalize_reward,
                gamma=float(self.cfg.hyperparams.get("gamma", 0.99)),
            )
        return venv

    def wall_s(self) -> float:
        return self.wall_before_s + time.perf_counter() - self._t0

    def write_status(self, model: BaseAlgorithm, finished: bool, ckpt: Checkpoint | None) -> None:
        self.status.update(
            {
                "steps_done": int(model.num_timesteps),
                "steps_target": self.cfg.steps,
                "finished": finished,
                "wall_s": round(self.wall_s(), 3),
                "segments": self.segment + 1,
                "updated_utc": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
            }
        )
        if ckpt is not None:
            self.status["latest_checkpoint"] = ckpt.model.name
        self.rd.write_status(self.status)

    def learn(self, model: BaseAlgorithm, extra: Sequence[BaseCallback] = ()) -> TrainResult:
        """SB3's ``learn`` with the run's callbacks (and ``extra`` ones); the wall-clock limit
        counts what this segment spent before it (a dagger stage)."""
        cfg, rd = self.cfg, self.rd
        model.set_logger(_logger(rd))
        start = int(model.num_timesteps)
        ckpt_cb = RunDirCheckpoint(
            rd,
            cfg.checkpoint_interval,
            cfg.save_replay,
            lambda c: self.write_status(model, False, c),
        )
        spent_s = time.perf_counter() - self._t0
        wall = WallClockLimit(max(cfg.max_wall_s - spent_s, 1e-3) if cfg.max_wall_s else 0.0)
        callbacks = CallbackList(
            [
                ProgressBar(cfg.steps, enabled=cfg.progress),
                EpisodeLog(rd.episodes_path, self.wall_before_s),
                ckpt_cb,
                wall,
                *extra,
            ]
        )
        self.write_status(model, False, None)
        t0 = time.perf_counter()
        try:
            model.learn(
                total_timesteps=max(cfg.steps - start, 0),
                callback=callbacks,
                log_interval=cfg.log_interval,
                reset_num_timesteps=False,
                tb_log_name="run",
            )
        except KeyboardInterrupt:  # leave a checkpoint so --resume loses nothing
            ckpt = save_checkpoint(model, rd, cfg.save_replay)
            self.write_status(model, False, ckpt)
            raise
        finally:
            # SB3 dumps before each update, so the last update's figures are still pending
            model.logger.dump(model.num_timesteps)
            model.logger.close()
        elapsed = time.perf_counter() - t0
        ckpt = save_checkpoint(model, rd, cfg.save_replay)
        vn = model.get_vec_normalize_env()
        if vn is not None:
            atomic_write(rd.vecnormalize_path, lambda fh: pickle.dump(vn, fh))
        atomic_write(rd.model_path, lambda fh: model.save(cast(io.BufferedIOBase, fh)))
        if wall.hit:
            self.status["stopped_by_wall_limit_s"] = cfg.max_wall_s
        self.write_status(model, True, ckpt)
        env = model.get_env()
        if env is not None:
            env.close()
        succ = model.ep_success_buffer
        return TrainResult(
            run_dir=rd.path,
            steps_done=int(model.num_timesteps),
            wall_s=self.wall_s(),
            steps_per_s=(model.num_timesteps - start) / max(elapsed, 1e-9),
            train_success_rate=float(np.mean(succ)) if succ else None,
            stopped_by_wall_limit=wall.hit,
        )


def train(cfg: TrainConfig) -> TrainResult:
    """Train from scratch into ``cfg.run_dir`` (which must be new or empty)."""
    th.set_num_threads(1)
    rd = RunDir(cfg.run_dir)
    if not rd.is_empty():
        raise RunDirError(
            f"run dir {cfg.run_dir!r} is not empty; pass --resume to continue it "
            "or choose a new --run-dir"
        )
    spec = load_spec(cfg.spec_path)
    dr = load_preset(cfg.dr)
    rd.path.mkdir(parents=True, exist_ok=True)
    try:
        session, model, meta = _setup(cfg, rd, spec, dr)
    except BaseException:  # nothing half-made stays behind: the folder was empty before
        shutil.rmtree(rd.path, ignore_errors=True)
        raise
    rd.write_meta(meta)
    if cfg.warm_start is not None:
        _warm_start(cfg, rd, model, meta)
    anchor = _dagger(cfg, rd, model) if cfg.dagger is not None else None
    return session.learn(model, () if anchor is None else (anchor,))


def _dagger(cfg: TrainConfig, rd: RunDir, model: BaseAlgorithm) -> BaseCallback | None:
    """Imitate the privileged teacher before the first update (``dagger``); the figures in
    ``dagger.json``. Returns the anchor that goes on imitating while the algorithm learns, if
    the preset asks for one. A failure leaves no half-started run behind."""
    from sim2real.train.atomic import atomic_write_json
    from sim2real.train.dagger import Dagger, DaggerStage

    try:
        model.set_logger(_logger(rd))
        stage = DaggerStage(model, cfg.algo, Dagger.from_mapping(cfg.dagger), cfg.seed)
        atomic_write_json(rd.path / "dagger.json", stage.run())
        return stage.anchor()
    except BaseException:
        env = model.get_env()
        with contextlib.suppress(Exception):
            if env is not None:
                env.close()
        shutil.rmtree(rd.path, ignore_errors=True)
        raise


def _warm_start(cfg: TrainConfig, rd: RunDir, model: BaseAlgorithm, meta: RunMeta) -> None:
    """The teacher's stages (``warmstart``) before the first update; their figures in
    ``warm_start.json``. A failure leaves no half-started run behind."""
    from sim2real.export.formats import load_policy
    from sim2real.train.atomic import atomic_write_json
    from sim2real.train.warmstart import WarmStart, check_teacher, warm_start

    ws = WarmStart.from_mapping(cfg.warm_start)
    try:
        teacher = load_policy(ws.teacher)
        check_teacher(ws.teacher, teacher.meta, cfg.env_id, meta.obs_layout, meta.action_dim)
        figures = warm_start(model, cfg.algo, ws, teacher, cfg.seed)
        atomic_write_json(rd.path / "warm_start.json", figures)
    except BaseException:
        env = model.get_env()
        # closing may fail itself (subprocess workers killed by the same Ctrl-C); the run is
        # removed either way
        with contextlib.suppress(Exception):
            if env is not None:
                env.close()
        shutil.rmtree(rd.path, ignore_errors=True)
        raise


def _setup(
    cfg: TrainConfig, rd: RunDir, spec: ArmSpec, dr: DRConfig
) -> tuple[_Session, BaseAlgorithm, RunMeta]:
    """Envs, model and the typed record of a new run."""
    session = _Session(cfg, rd, spec, dr)
    venv = session.vec_env(None)
    algo = session.algo
    policy_cls: Any = cfg.policy or policy_for(venv.observation_space)
    if cfg.uses_privileged:
        policy_cls = AsymmetricActorCriticPolicy
    policy = policy_cls if isinstance(policy_cls, str) else policy_cls.__name__
    try:
        space = venv.action_space
        n_actions = int(np.prod(space.shape)) if isinstance(space, gym.spaces.Box) else 0
        model = algo.cls(
            policy_cls,
            venv,
            seed=cfg.seed,
            device=torch_device(),
            verbose=0,
            **_hyperparams(cfg, algo, n_actions),
        )
    except (TypeError, ValueError, AssertionError, KeyError) as exc:
        venv.close()
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ConfigError(f"{cfg.algo} rejected the configuration: {msg}") from None
    venv.seed(session.seeds[0])  # model seeding reseeded the envs; restore the recorded seeds
    vn = venv if isinstance(venv, VecNormalize) else None
    table = session.table
    meta = RunMeta(
        env_id=cfg.env_id,
        algo=cfg.algo,
        policy=policy,
        dr=dr.name,
        dr_source=cfg.dr,
        dr_ranges=dr.to_dict(),
        seed=cfg.seed,
        steps=cfg.steps,
        spec=spec.to_dict(),
        spec_name=spec.name,
        spec_fingerprint=spec.fingerprint(),
        training_seeds=tuple(session.seeds),
        normalize=cfg.normalize,
        # What the VecNormalize really does (None: no wrapper, no vecnormalize.pkl): image
        # observations are never normalised, whatever ``normalize`` says.
        vecnormalize=None
        if vn is None
        else {
            "norm_obs": vn.norm_obs,
            "norm_obs_keys": vn.norm_obs_keys,
            "norm_reward": vn.norm_reward,
        },
        action_table=None if table is None else tuple(tuple(map(float, r)) for r in table),
        env_kwargs=dict(cfg.env_kwargs),
        train=cfg.to_dict(),
        versions=versions(),
        created_utc=dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
        source=str(rd.path),
        **session.obs_desc,
    )
    return session, model, meta


def resume(
    run_dir: str | Path,
    steps: int | None = None,
    progress: bool | None = None,
    max_wall_s: float | None = None,
) -> TrainResult:
    """Continue a run from its newest checkpoint; ``steps`` may raise the total budget."""
    th.set_num_threads(1)
    rd = RunDir(run_dir)
    meta = rd.read_meta()
    ckpt = rd.latest_checkpoint()
    if ckpt is None:
        raise RunDirError(f"run dir {str(run_dir)!r} has no checkpoint to resume from")
    train_dict = dict(meta.train)
    if steps is not None:
        if steps < ckpt.steps:
            raise ConfigError(
                f"--steps {steps} is below the {ckpt.steps} steps the run already has"
            )
        train_dict["steps"] = steps
    if progress is not None:
        train_dict["progress"] = progress
    if max_wall_s is not None:
        train_dict["max_wall_s"] = max_wall_s
    train_dict["run_dir"] = str(run_dir)
    try:
        cfg = TrainConfig.from_dict(train_dict)
        spec = ArmSpec.from_dict(dict(meta.spec), source=f"{run_dir}/config.json spec")
        dr = DRConfig.from_dict(meta.dr, meta.dr_ranges)
    except (KeyError, TypeError) as exc:
        raise RunDirError(f"run dir {str(run_dir)!r}: bad config.json ({exc})") from None
    if spec.fingerprint() != meta.spec_fingerprint:
        raise RunDirError(f"run dir {str(run_dir)!r}: spec does not match its fingerprint")
    session = _Session(cfg, rd, spec, dr)
    if ckpt.steps >= cfg.steps and rd.read_status().get("finished"):
        raise RunDirError(
            f"run dir {str(run_dir)!r} already finished {ckpt.steps} steps; "
            "pass a larger --steps to train further"
        )
    venv = session.vec_env(ckpt.vecnormalize)
    algo = session.algo
    try:
        model = algo.cls.load(str(ckpt.model), env=venv, device=torch_device())  # type: ignore[attr-defined]
    except Exception as exc:  # a truncated zip, a pickle from another version
        venv.close()
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise RunDirError(
            f"run dir {str(run_dir)!r}: cannot load {ckpt.model.name} ({msg})"
        ) from None
    if ckpt.replay is not None and hasattr(model, "load_replay_buffer"):
        model.load_replay_buffer(str(ckpt.replay))
    venv.seed(session.seeds[0])
    seeds = tuple(sorted(set(meta.training_seeds) | set(session.seeds)))
    rd.write_meta(replace(meta, training_seeds=seeds, steps=cfg.steps, train=cfg.to_dict()))
    return session.learn(model, _resumed_anchor(cfg, model))


def _resumed_anchor(cfg: TrainConfig, model: BaseAlgorithm) -> tuple[BaseCallback, ...]:
    """A dagger run's anchor goes on in a resumed segment (an ``adapt`` fine-tune is one), its
    dataset filled anew by the teacher from the states the learner visits; without it the
    algorithm alone undoes the imitation (``dagger``'s measurements)."""
    if cfg.dagger is None:
        return ()
    from sim2real.train.dagger import Dagger, DaggerStage

    anchor = DaggerStage(model, cfg.algo, Dagger.from_mapping(cfg.dagger), cfg.seed).anchor()
    return () if anchor is None else (anchor,)
