"""Training configuration: a hyperparameter preset per (algo, env), CLI overrides, validation.

Presets are YAML files in ``presets/`` named ``<algo>_<env short name>.yaml`` (``ppo_reach``,
``sac_pick_goal``), falling back to ``<algo>_<task>`` and then ``<algo>_default``. Every field of a
preset can be overridden with ``--set KEY=VALUE`` (the value is parsed as YAML); a KEY that is not
a top-level preset field is taken as an SB3 constructor argument (``--set learning_rate=3e-4`` is
``--set hyperparams.learning_rate=3e-4``).
"""

from __future__ import annotations

import copy
import inspect
from collections.abc import Mapping, Sequence
from dataclasses import Field, dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from sim2real.errors import ConfigError, UnknownNameError
from sim2real.held_out import EVAL_SEED_BASE  # evaluation seeds; training seeds stay below

PRESET_DIR = Path(__file__).with_name("presets")
VEC_ENVS: tuple[str, ...] = ("dummy", "subproc")
# Keys of the ``augment`` preset mapping (pixel policies only, see augment.py).
AUGMENT_KEYS: tuple[str, ...] = ("random_shift_px",)
# SB3 constructor arguments the trainer sets itself.
MANAGED_HYPERPARAMS: frozenset[str] = frozenset(
    {
        "policy",
        "env",
        "seed",
        "verbose",
        "device",
        "tensorboard_log",
        "_init_setup_model",
        "action_noise",
        "replay_buffer_class",
    }
)
MANAGED_ENV_KWARGS: frozenset[str] = frozenset({"dr", "spec", "render_mode", "task"})
ACTION_NOISES: tuple[str, ...] = ("normal", "ornstein_uhlenbeck")
SCHEDULE_PREFIX = "lin_"  # "lin_1e-3": linear decay from 1e-3 to 0 over the run
SCHEDULABLE: tuple[str, ...] = ("learning_rate", "clip_range")


@dataclass(frozen=True)
class TrainConfig:
    """Everything that decides a training run; written to ``config.json`` in the run dir."""

    env_id: str
    algo: str
    run_dir: str
    dr: str = "default"
    steps: int = 100_000
    seed: int = 0
    n_envs: int = 1
    vec_env: str = "dummy"
    her: bool = False
    normalize: bool = True
    normalize_reward: bool = False
    policy: str | None = None
    hyperparams: Mapping[str, Any] = field(default_factory=dict)
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)
    her_kwargs: Mapping[str, Any] = field(default_factory=dict)
    action_noise: Mapping[str, Any] | None = None
    discrete_magnitudes: tuple[float, ...] = (1.0, 0.2)
    checkpoint_every: int = 0  # env steps between checkpoints; 0 = five per run
    log_interval: int = 1
    save_replay: bool = True
    action_rate_penalty: float = 0.0  # training-only reward shaping, see wrappers.py
    start_curriculum: Mapping[str, Any] | None = None  # training-only resets, see wrappers.py
    max_wall_s: float = 0.0  # stop (and save) after this much wall time; 0 = no limit
    augment: Mapping[str, Any] | None = None  # image augmentation in updates, see augment.py
    privileged_critic: bool = False  # asymmetric actor-critic, see asymmetric.py
    warm_start: Mapping[str, Any] | None = None  # start from a teacher's experience, warmstart.py
    dagger: Mapping[str, Any] | None = None  # imitate a privileged teacher first, dagger.py
    spec_path: str | None = None
    preset: str = ""
    progress: bool = True

    def __post_init__(self) -> None:
        import sim2real.envs as envs
        from sim2real.randomization import load_preset
        from sim2real.train.algos import get_algo

        object.__setattr__(self, "env_id", envs.resolve_env_id(self.env_id))
        algo = get_algo(self.algo)
        object.__setattr__(self, "algo", algo.name)
        check_action_space(algo.name, self.env_id, envs.has_discrete_actions(self.env_id))
        load_preset(self.dr)  # unknown names / bad files fail here, before anything is written
        for name in ("steps", "n_envs", "log_interval"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ConfigError(f"{name} must be an integer >= 1, got {value!r}")
        if not isinstance(self.checkpoint_every, int) or self.checkpoint_every < 0:
            raise ConfigError(
                f"checkpoint_every must be an integer >= 0, got {self.checkpoint_every!r}"
            )
        if not isinstance(self.seed, int) or not 0 <= self.seed < EVAL_SEED_BASE // 2:
            raise ConfigError(
                f"seed must be an integer in [0, {EVAL_SEED_BASE // 2}), got {self.seed!r}"
            )
        if self.vec_env not in VEC_ENVS:
            raise UnknownNameError("vec_env", str(self.vec_env), VEC_ENVS)
        if self.her:
            if not algo.off_policy:
                off = sorted(n for n, a in _algos().items() if a.off_policy)
                raise ConfigError(
                    f"--her needs an off-policy algo ({', '.join(off)}); got {algo.name!r}"
                )
            if not is_goal_env(self.env_id):
                goal = [e.id for e in envs.ENV_TABLE if e.kwargs.get("obs_mode") == "goal"]
                raise ConfigError(
                    f"--her needs a goal-conditioned env ({', '.join(goal)}); got {self.env_id!r}"
                )
        if self.action_noise is not None:
            if not isinstance(self.action_noise, Mapping):
                raise ConfigError(
                    f"action_noise must be a mapping like {{type: normal, sigma: 0.1}}, "
                    f"got {self.action_noise!r}"
                )
            kind = self.action_noise.get("type")
            if kind not in ACTION_NOISES:
                raise UnknownNameError("action_noise type", str(kind), ACTION_NOISES)
            if not algo.action_noise:
                raise ConfigError(f"action_noise is not used by {algo.name!r}; remove it")
        if (
            not isinstance(self.action_rate_penalty, int | float)
            or not self.action_rate_penalty >= 0
        ):
            raise ConfigError(
                f"action_rate_penalty must be a number >= 0, got {self.action_rate_penalty!r}"
            )
        if not isinstance(self.max_wall_s, int | float) or not self.max_wall_s >= 0:
            raise ConfigError(f"max_wall_s must be a number >= 0, got {self.max_wall_s!r}")
        if self.action_rate_penalty and self.her:
            raise ConfigError(
                "action_rate_penalty cannot be used with --her (HER recomputes rewards)"
            )
        if self.start_curriculum is not None:
            _check_start_curriculum(self.env_id, self.start_curriculum)
            object.__setattr__(self, "start_curriculum", dict(self.start_curriculum))
        if self.augment is not None:
            _check_augment(self.augment)
            object.__setattr__(self, "augment", dict(self.augment))
        if not isinstance(self.privileged_critic, bool):
            raise ConfigError(
                f"privileged_critic must be true or false, got {self.privileged_critic!r}"
            )
        if self.privileged_critic and not algo.privileged_critic:
            ok = sorted(n for n, a in _algos().items() if a.privileged_critic)
            raise ConfigError(
                f"privileged_critic needs an algo with a separate critic ({', '.join(ok)}); "
                f"got {algo.name!r}"
            )
        if (self.privileged_critic or algo.needs_privileged) and self.policy is not None:
            raise ConfigError(
                f"policy {self.policy!r}: an asymmetric or distilled run builds its own policy"
            )
        if self.warm_start is not None:
            from sim2real.train.warmstart import WarmStart, check_algo

            check_algo(algo.name)
            if self.her:
                raise ConfigError("warm_start cannot be used with --her (a flat observation)")
            WarmStart.from_mapping(self.warm_start)
            object.__setattr__(self, "warm_start", dict(self.warm_start))
        if self.dagger is not None:
            from sim2real.train.dagger import Dagger
            from sim2real.train.dagger import check_algo as check_dagger_algo

            check_dagger_algo(algo.name)
            if self.her or self.warm_start is not None or self.uses_privileged:
                raise ConfigError(
                    "dagger trains a state student: not with --her, warm_start, a privileged "
                    "critic or a distilled run"
                )
            Dagger.from_mapping(self.dagger)
            object.__setattr__(self, "dagger", dict(self.dagger))
        _check_hyperparams(algo.name, self.hyperparams)
        _check_env_kwargs(self.env_id, self.env_kwargs)
        object.__setattr__(
            self, "discrete_magnitudes", tuple(float(m) for m in self.discrete_magnitudes)
        )

    @property
    def uses_privileged(self) -> bool:
        """Training envs carry the privileged state (an asymmetric critic or a teacher)."""
        from sim2real.train.algos import get_algo

        return self.privileged_critic or get_algo(self.algo).needs_privileged

    @property
    def checkpoint_interval(self) -> int:
        return self.checkpoint_every or max(self.steps // 5, 1)

    def to_dict(self) -> dict[str, Any]:
        """Every field, JSON-ready (mappings copied, tuples as lists)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, Mapping):
                value = copy.deepcopy(dict(value))
            elif isinstance(value, tuple):
                value = list(value)
            out[f.name] = value
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TrainConfig:
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"train config: unknown key(s) {unknown}; valid: {sorted(known)}")
        kw = dict(data)
        if "discrete_magnitudes" in kw:
            kw["discrete_magnitudes"] = tuple(kw["discrete_magnitudes"])
        return cls(**kw)


# TrainConfig fields a preset file does not set: the command line and the trainer do. Every other
# field is a preset key of the same name, except ``her``: in a preset it holds HER's options
# (``her_kwargs``), on the command line it is the ``--her`` switch.
NOT_PRESET_FIELDS: frozenset[str] = frozenset(
    {"env_id", "run_dir", "dr", "seed", "her_kwargs", "spec_path", "preset", "progress"}
)
PRESET_KEYS: tuple[str, ...] = tuple(
    f.name for f in fields(TrainConfig) if f.name not in NOT_PRESET_FIELDS
)


def _algos() -> Mapping[str, Any]:
    from sim2real.train.algos import ALGOS

    return ALGOS


def check_action_space(algo: str, env_id: str, discrete: bool) -> None:
    """An env with its own ``Discrete`` actions trains as-is: only algos that take one can."""
    if discrete and not _algos()[algo].accepts_discrete:
        ok = sorted(n for n, a in _algos().items() if a.accepts_discrete)
        raise ConfigError(
            f"{algo} needs continuous actions but {env_id} has discrete actions; "
            f"use one of: {', '.join(ok)}"
        )


def is_goal_env(env_id: str) -> bool:
    import sim2real.envs as envs

    entry = next(e for e in envs.ENV_TABLE if e.id == envs.resolve_env_id(env_id))
    return entry.kwargs.get("obs_mode") == "goal"


def _check_start_curriculum(env_id: str, sc: Any) -> None:
    """``{held_prob: p}``, p in [0, 1], on an env whose task has a held start (pick)."""
    import sim2real.envs as envs
    from sim2real.envs.base import START_HELD
    from sim2real.train.wrappers import START_CURRICULUM_KEYS, check_held_prob

    if not isinstance(sc, Mapping):
        raise ConfigError(f"start_curriculum must be a mapping like {{held_prob: 0.5}}, got {sc!r}")
    _reject_unknown_keys(sc, START_CURRICULUM_KEYS, "start_curriculum")
    check_held_prob(sc.get("held_prob", 0.0))
    entry = next(e for e in envs.ENV_TABLE if e.id == env_id)
    task = envs.TASKS.get(str(entry.kwargs.get("task")))
    arm_env = entry.entry_point in (envs.ENTRY_POINT, envs.GOAL_ENTRY_POINT)
    if not arm_env or task is None or START_HELD not in task.start_modes:
        raise ConfigError(
            f"start_curriculum: {env_id} has no {START_HELD!r} start (only tasks that grasp an "
            "object, e.g. Sim2Real/Arm3Pick-v0)"
        )


def _check_augment(aug: Any) -> None:
    """``{random_shift_px: n}``; the trainer checks that the env observes an image."""
    from sim2real.train.augment import check_shift_px

    if not isinstance(aug, Mapping):
        raise ConfigError(f"augment must be a mapping like {{random_shift_px: 4}}, got {aug!r}")
    _reject_unknown_keys(aug, AUGMENT_KEYS, "augment")
    check_shift_px(aug.get("random_shift_px", 0))


def constructor_params(cls: type) -> set[str]:
    """Keyword arguments a class accepts, through subclasses that pass ``**kwargs`` on."""
    out: set[str] = set()
    for klass in cls.__mro__:
        if "__init__" not in vars(klass):
            continue
        params = inspect.signature(vars(klass)["__init__"]).parameters
        out |= {
            n
            for n, p in params.items()
            if p.kind is p.KEYWORD_ONLY or p.kind is p.POSITIONAL_OR_KEYWORD
        }
        if not any(p.kind is p.VAR_KEYWORD for p in params.values()):
            break
    return out - {"self"}


def _check_hyperparams(algo: str, hp: Mapping[str, Any]) -> None:
    cls = _algos()[algo].cls
    params = constructor_params(cls)
    allowed = params - MANAGED_HYPERPARAMS
    unknown = sorted(set(hp) - allowed)
    if unknown:
        raise ConfigError(
            f"unknown {algo} hyperparameter(s) {unknown}; valid: {', '.join(sorted(allowed))}"
        )
    own_check = getattr(cls, "check_hyperparams", None)
    if own_check is not None:
        own_check(dict(hp))
    for key in SCHEDULABLE:
        value = hp.get(key)
        if isinstance(value, str):
            try:
                if not value.startswith(SCHEDULE_PREFIX):
                    raise ValueError
                float(value.removeprefix(SCHEDULE_PREFIX))
            except ValueError:
                raise ConfigError(
                    f"{algo} {key} {value!r}: give a number or {SCHEDULE_PREFIX}<start>, "
                    f"e.g. {SCHEDULE_PREFIX}1e-3"
                ) from None
    act = (hp.get("policy_kwargs") or {}).get("activation_fn")
    if act is not None:
        from sim2real.train.algos import ACTIVATIONS

        if act not in ACTIVATIONS:
            raise UnknownNameError("activation_fn", str(act), ACTIVATIONS)
    extractor = (hp.get("policy_kwargs") or {}).get("features_extractor")
    if extractor is not None:
        from sim2real.train.extractors import get_extractor

        get_extractor(str(extractor))


def _check_env_kwargs(env_id: str, kw: Mapping[str, Any]) -> None:
    """Checked against the registered env class's own constructor: robosuite and Kuka envs take
    ``robot``/``controller``/``objects`` that the arm envs do not."""
    import importlib

    import sim2real.envs as envs

    entry = next(e for e in envs.ENV_TABLE if e.id == envs.resolve_env_id(env_id))
    module_name, _, class_name = entry.entry_point.partition(":")
    env_cls = getattr(importlib.import_module(module_name), class_name)
    params = set(inspect.signature(env_cls.__init__).parameters) - {"self"}
    allowed = params - MANAGED_ENV_KWARGS - set(entry.kwargs)
    unknown = sorted(set(kw) - allowed)
    if unknown:
        raise ConfigError(
            f"unknown env_kwargs {unknown} for {entry.id}; valid: {', '.join(sorted(allowed))}"
        )


# ---- presets ---------------------------------------------------------------------------------
def preset_names() -> list[str]:
    return sorted(p.stem for p in PRESET_DIR.glob("*.yaml"))


def preset_candidates(algo: str, env_id: str) -> list[str]:
    """Names tried in order: the exact env, the env it shares presets with (``presets_from``),
    the env's task (only for variants that share its observation and reward: a goal, pixel or
    sparse variant needs its own), the algorithm's default."""
    import sim2real.envs as envs

    entry = next(e for e in envs.ENV_TABLE if e.id == envs.resolve_env_id(env_id))
    short = entry.short.replace("-", "_")
    task = str(entry.kwargs.get("task", short))
    names = [f"{algo}_{short}"]
    if entry.presets_from:
        names.append(f"{algo}_{entry.presets_from.replace('-', '_')}")
    if set(entry.kwargs) <= {"task"}:
        names.append(f"{algo}_{task}")
    names.append(f"{algo}_default")
    return list(dict.fromkeys(names))


def find_preset(algo: str, env_id: str, preset: str | None = None) -> Path:
    if preset:
        path = Path(preset)
        if preset.endswith((".yaml", ".yml")) or path.is_file():
            if not path.is_file():
                raise ConfigError(f"preset file {preset!r} does not exist")
            return path
        named = PRESET_DIR / f"{preset}.yaml"
        if not named.is_file():
            raise UnknownNameError("preset", preset, preset_names())
        return named
    for name in preset_candidates(algo, env_id):
        path = PRESET_DIR / f"{name}.yaml"
        if path.is_file():
            return path
    raise ConfigError(f"no preset for algo {algo!r} and env {env_id!r}")  # pragma: no cover


def read_preset(path: Path) -> dict[str, Any]:
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(
            f"preset {str(path)!r} is not valid YAML: {exc}".splitlines()[0]
        ) from None
    if not isinstance(data, dict):
        raise ConfigError(f"preset {str(path)!r} must be a mapping")
    _reject_unknown_keys(data, PRESET_KEYS, f"preset {str(path)!r}")
    return data


def _reject_unknown_keys(data: Mapping[str, Any], valid: Sequence[str], what: str) -> None:
    unknown = sorted(set(data) - set(valid))
    if unknown:
        raise ConfigError(f"{what}: unknown key(s) {unknown}; valid: {list(valid)}")


def apply_overrides(preset: Mapping[str, Any], overrides: Sequence[str]) -> dict[str, Any]:
    """``KEY=VALUE`` strings into a copy of ``preset`` (dotted keys reach nested mappings)."""
    out = copy.deepcopy(dict(preset))
    for item in overrides:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f"override {item!r} must look like KEY=VALUE")
        try:
            value = yaml.safe_load(raw)
        except yaml.YAMLError:
            raise ConfigError(f"override {item!r}: value is not valid YAML") from None
        parts = key.split(".")
        if parts[0] not in PRESET_KEYS:
            parts = ["hyperparams", *parts]
        node = out
        for p in parts[:-1]:
            child = node.get(p)
            if child is None:
                child = node[p] = {}
            if not isinstance(child, dict):
                raise ConfigError(f"override {item!r}: {p!r} is not a mapping")
            node = child
        node[parts[-1]] = value
    return out


def resolve_config(
    env: str,
    algo: str,
    run_dir: str | Path,
    *,
    dr: str = "default",
    seed: int = 0,
    steps: int | None = None,
    n_envs: int | None = None,
    vec_env: str | None = None,
    her: bool = False,
    preset: str | None = None,
    overrides: Sequence[str] = (),
    spec_path: str | None = None,
    progress: bool = True,
    max_wall_s: float | None = None,
) -> TrainConfig:
    """Preset file → ``--set`` overrides → explicit flags, into one validated ``TrainConfig``."""
    import sim2real.envs as envs
    from sim2real.train.algos import get_algo

    env_id = envs.resolve_env_id(env)
    algo_name = get_algo(algo).name
    path = find_preset(algo_name, env_id, preset)
    data = apply_overrides(read_preset(path), overrides)
    if data.get("algo", algo_name) != algo_name:
        raise ConfigError(f"preset {path.stem!r} is for algo {data['algo']!r}, not {algo_name!r}")
    flags = {"steps": steps, "n_envs": n_envs, "vec_env": vec_env}
    set_keys = {o.partition("=")[0].strip() for o in overrides}
    for name, value in flags.items():
        if value is None:
            continue
        if name in set_keys and data[name] != value:
            raise ConfigError(
                f"conflicting flags: --{name.replace('_', '-')} {value} and --set {name}={data[name]}"
            )
        data[name] = value
    her_kwargs = data.get("her") or {}
    if not isinstance(her_kwargs, dict):
        raise ConfigError(f"preset {path.stem!r}: 'her' must be a mapping of HER options")
    values = {
        f.name: _preset_value(f, data[f.name])
        for f in fields(TrainConfig)
        if f.name in PRESET_KEYS and f.name not in ("algo", "her") and f.name in data
    }
    if max_wall_s is not None:
        values["max_wall_s"] = max_wall_s
    return TrainConfig(
        env_id=env_id,
        algo=algo_name,
        run_dir=str(run_dir),
        dr=dr,
        seed=seed,
        her=her,
        her_kwargs=dict(her_kwargs),
        spec_path=spec_path,
        preset=path.stem if path.parent == PRESET_DIR else str(path),
        progress=progress,
        **values,
    )


def _preset_value(f: Field[Any], value: Any) -> Any:
    """A preset's value in the field's type: switches must be booleans, mappings may be empty."""
    if isinstance(f.default, bool):
        return _as_bool(f.name, value)
    if f.default_factory is dict:
        return dict(value or {})
    if isinstance(f.default, tuple):
        return _as_floats(f.name, value)
    if isinstance(f.default, str):
        return str(value)
    return value


def _as_bool(name: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ConfigError(f"{name} must be true or false, got {value!r}")
    return value


def _as_floats(name: str, value: Any) -> tuple[float, ...]:
    try:
        return tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be a list of numbers, got {value!r}") from None
