"""``RunMeta``: the one typed, versioned record of what a training run and an exported policy carry.

A run directory's ``config.json`` and the JSON an exported ``.onnx``/``.npz`` policy embeds are
the same record: env id, task, observation layout, action decoding, the arm spec and its
fingerprint, the DR it trained under, the algorithm, seeds and library versions. It is written by
``RunMeta.to_dict`` and read by ``RunMeta.from_dict`` only, so every reader gets the same checks:
a field of the wrong type is one line naming the field, an unknown format one line naming the
version. Older records (run directories of format 1, and the untyped ``PolicyMeta`` JSON with an
``extra`` catch-all that the shipped policies embed) are converted on read.

Only the standard library is imported: the deploy runtime on the computer beside the arm reads it.
"""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
from typing import TYPE_CHECKING, Any

from sim2real.errors import Sim2RealError, UnknownNameError

if TYPE_CHECKING:
    from hardware.spec import ArmSpec

FORMAT = 2  # the format this version writes
OPTIONAL_FIELDS: frozenset[str] = frozenset(
    {"exported_from", "export_format", "note", "adapted_from", "obs_key_shapes"}
)
READABLE_FORMATS: tuple[int, ...] = (1, 2)
# A spec record leaves a measured reading's kind out (``hardware.spec.DEFAULT_FEEDBACK``).
DEFAULT_READING = "measured"
# What each reading kind is, for a refusal (``hardware.spec.FEEDBACK_KINDS``, in brief).
READING_NOTES: dict[str, str] = {
    "measured": "a sensor on the horn: an encoder or a potentiometer",
    "commanded": "the pulse each servo was sent: bare PWM servos",
}


class MetaError(Sim2RealError):
    """Run or policy metadata that cannot be read: bad JSON, wrong type, unknown format."""


class PolicyError(Sim2RealError):
    """A policy file is unusable, or does not fit the arm or the observation it is given."""


@dataclass(frozen=True)
class ObsField:
    """One named slice of the flat observation (the ``ObservationBuilder`` layout)."""

    name: str
    start: int
    stop: int
    unit: str = ""
    doc: str = ""

    @property
    def size(self) -> int:
        return self.stop - self.start


@dataclass(frozen=True)
class RunMeta:
    """What a run (``config.json``) and an exported policy (embedded JSON) carry.

    ``source`` is where the record was read from (a run dir or a policy file): it is used in
    messages and never written.
    """

    # Required in the constructor: what every check needs. The defaults below only make
    # small records easy to build (tests); ``from_dict`` requires every field but those in
    # ``OPTIONAL_FIELDS``.
    env_id: str
    algo: str
    dr: str  # the DR preset's name
    spec_name: str
    spec_fingerprint: str
    obs_shape: tuple[int, ...]
    # action decoding: a Box policy outputs action_dim values in [-1, 1]; a Discrete env's one
    # index out of n_actions; a discrete-only algo on a Box env indexes rows of action_table
    action_dim: int
    task: str = ""  # the env's task ("reach", "pick", ...); "" for envs without one
    policy: str = ""  # the SB3 policy class name ("" in policies exported before format 2)
    # the observation contract
    obs_mode: str = "state"  # "state", "goal" or "pixels"
    obs_layout: tuple[ObsField, ...] = ()
    obs_keys: tuple[str, ...] | None = None  # dict observations: flattened in this order
    obs_key_sizes: tuple[int, ...] | None = None
    n_actions: int | None = None
    action_table: tuple[tuple[float, ...], ...] | None = None
    max_delta_rad: float = 0.1  # joint-target change of a full action, per step
    control_hz: float = 20.0
    # the arm: ArmSpec.to_dict(), enough to rebuild the env from a policy file alone
    spec: Mapping[str, Any] = field(default_factory=dict)
    # domain randomisation: what was asked for (a preset name or a YAML path), and its ranges
    dr_source: str = ""
    dr_ranges: Mapping[str, Any] | None = None
    # seeds and budget
    seed: int = 0
    steps: int = 0
    training_seeds: tuple[int, ...] = ()
    # everything else the trainer resolved
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)
    normalize: bool = True
    vecnormalize: Mapping[str, Any] | None = None  # None: no VecNormalize, no vecnormalize.pkl
    train: Mapping[str, Any] = field(default_factory=dict)  # TrainConfig.to_dict()
    versions: Mapping[str, str] = field(default_factory=dict)
    created_utc: str = ""
    # optional in a record
    exported_from: str = ""  # an exported policy: the run dir it came from
    export_format: str = ""  # an exported policy: "onnx" or "numpy"
    note: str = ""
    adapted_from: Mapping[str, Any] | None = None  # a fine-tune (``sim2real adapt``): its source
    # dict observations: each key's own shape (an image's rows, columns and channels), so a flat
    # row unflattens to what the env gave; None in records written before it
    obs_key_shapes: tuple[tuple[int, ...], ...] | None = None
    source: str = field(default="", compare=False)

    # ---- derived ------------------------------------------------------------------------------
    @property
    def flat_obs_dim(self) -> int:
        n = 1
        for s in self.obs_shape:
            n *= s
        return n

    @property
    def layout_sizes(self) -> list[tuple[str, int]]:
        return [(f.name, f.size) for f in self.obs_layout]

    def reading_kinds(self) -> dict[str, str] | None:
        """Actuator name → the reading kind the policy was trained on (``measured`` or
        ``commanded``), from its spec record; None where the record holds no spec."""
        joints = self.spec.get("joints")
        if not isinstance(joints, list | tuple) or not joints:
            return None
        actuators = [*joints, *([self.spec["gripper"]] if self.spec.get("gripper") else [])]
        try:
            return {str(a["name"]): str(a.get("feedback", DEFAULT_READING)) for a in actuators}
        except (TypeError, KeyError, AttributeError):
            return None

    def check_spec(self, spec: ArmSpec | str) -> None:
        """Refuse an arm whose spec (or fingerprint) differs from the one the policy was trained
        for. Given the spec, a difference in reading kinds is said first, in one line: a policy
        trained on measured readings would run on echoes of its commands (or the reverse)."""
        fingerprint = spec if isinstance(spec, str) else spec.fingerprint()
        if fingerprint == self.spec_fingerprint:
            return
        why = "" if isinstance(spec, str) else self._readings_refusal(spec, fingerprint)
        raise PolicyError(
            why
            or f"policy {self.source!r} was trained for arm spec {self.spec_name!r} "
            f"(fingerprint {self.spec_fingerprint}), not for fingerprint {fingerprint}"
        )

    def _readings_refusal(self, spec: ArmSpec, fingerprint: str) -> str:
        """Why ``spec`` is refused when its reading kinds differ from the trained ones ("" when
        they agree, or the record cannot tell)."""
        trained = self.reading_kinds()
        arm = dict(zip(spec.actuator_names, spec.actuator_feedback, strict=True))
        if trained is None or set(trained) != set(arm):
            return ""
        differ: dict[str, list[str]] = {}
        for name, kind in arm.items():
            if kind != trained[name]:
                differ.setdefault(kind, []).append(name)
        if not differ:
            return ""
        kinds = set(trained.values())
        was = (
            f"{kinds.pop()} joint readings"
            if len(kinds) == 1
            else "readings " + ", ".join(f"{n} {k}" for n, k in trained.items())
        )
        reads = "; ".join(
            f"{', '.join(names)} {kind} ({READING_NOTES.get(kind, kind)})"
            for kind, names in differ.items()
        )
        # the same arm but for its readings (and its name)?
        as_trained = replace(spec.with_feedback(trained), name=self.spec_name)
        more = (
            ""
            if as_trained.fingerprint() == self.spec_fingerprint
            else f" (the spec differs in more than its readings: trained for fingerprint "
            f"{self.spec_fingerprint}, this is {fingerprint})"
        )
        return (
            f"policy {self.source!r} was trained on {was}; this arm's spec {spec.name!r} reads "
            f"{reads}: train on its spec (sim2real train --spec <its yaml>), or deploy a policy "
            f"trained on these readings{more}"
        )

    def check_layout(self, names_sizes: list[tuple[str, int]]) -> None:
        """Refuse an observation layout other than the policy's: same size is not same meaning."""
        trained = self.layout_sizes
        if trained and trained != names_sizes:
            raise PolicyError(
                f"policy {self.source!r} was trained on observation layout "
                f"{[n for n, _ in trained]}; this version builds {[n for n, _ in names_sizes]} "
                "(retrain the policy)"
            )

    # ---- the one writer and the one reader ---------------------------------------------------
    def __post_init__(self) -> None:
        """A dict observation's keys, sizes and shapes must describe the same columns: every
        reader slices the flat observation by them."""
        keys, sizes, shapes = self.obs_keys, self.obs_key_sizes, self.obs_key_shapes
        if keys is None:
            if sizes is not None or shapes is not None:
                raise MetaError(f"{self.source or 'record'}: obs_key_sizes/shapes without obs_keys")
            return
        if sizes is None or len(sizes) != len(keys):
            raise MetaError(
                f"{self.source or 'record'}: obs_key_sizes {sizes} do not match obs_keys {keys}"
            )
        if shapes is not None and [math.prod(s) for s in shapes] != list(sizes):
            raise MetaError(
                f"{self.source or 'record'}: obs_key_shapes {shapes} do not match "
                f"obs_key_sizes {sizes}"
            )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, with ``format``; ``source`` is not written, nor ``obs_key_shapes`` where
        there is none (a reader from before that field still reads the record)."""
        out: dict[str, Any] = {"format": FORMAT}
        for f in fields(self):
            if f.name == "source" or (f.name == "obs_key_shapes" and self.obs_key_shapes is None):
                continue
            out[f.name] = _plain(getattr(self, f.name))
        return out

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, data: Any, source: str = "") -> RunMeta:
        """A record of any readable format; anything else is one ``MetaError`` line."""
        where = f"metadata of {source!r}" if source else "metadata"
        if not isinstance(data, Mapping):
            raise MetaError(f"{where} is not a mapping")
        if "format" not in data and "extra" in data:
            data = _from_policy_meta_v1(data)
        version = data.get("format")
        if version not in READABLE_FORMATS or isinstance(version, bool):
            raise MetaError(
                f"{where} has format {version!r}; this version reads formats "
                f"{', '.join(map(str, READABLE_FORMATS))}"
            )
        if version == 1:
            data = _from_run_config_v1(data)
        return _build(cls, data, where, source)

    @classmethod
    def from_json(cls, text: str, source: str = "") -> RunMeta:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            where = f"metadata of {source!r}" if source else "metadata"
            raise MetaError(f"{where} is not valid JSON ({exc})") from None
        return cls.from_dict(data, source)

    def with_source(self, source: str) -> RunMeta:
        return replace(self, source=source)


# ---- field checks: one converter per field, named in the message when it refuses ---------------
class _BadValueError(Exception):
    def __init__(self, expected: str) -> None:
        self.expected = expected


Check = Callable[[Any], Any]


def _str(v: Any) -> str:
    if not isinstance(v, str):
        raise _BadValueError("a string")
    return v


def _int(v: Any) -> int:
    if not isinstance(v, int) or isinstance(v, bool):
        raise _BadValueError("an integer")
    return v


def _float(v: Any) -> float:
    if not isinstance(v, int | float) or isinstance(v, bool):
        raise _BadValueError("a number")
    return float(v)


def _bool(v: Any) -> bool:
    if not isinstance(v, bool):
        raise _BadValueError("true or false")
    return v


def _mapping(v: Any) -> dict[str, Any]:
    if not isinstance(v, Mapping) or not all(isinstance(k, str) for k in v):
        raise _BadValueError("a mapping")
    return copy.deepcopy(dict(v))


def _opt(check: Check) -> Check:
    def inner(v: Any) -> Any:
        return None if v is None else check(v)

    return inner


def _tuple_of(check: Check, what: str) -> Check:
    def inner(v: Any) -> tuple[Any, ...]:
        if not isinstance(v, list | tuple):
            raise _BadValueError(f"a list of {what}")
        try:
            return tuple(check(x) for x in v)
        except _BadValueError:
            raise _BadValueError(f"a list of {what}") from None

    return inner


def _obs_field(v: Any) -> ObsField:
    if isinstance(v, ObsField):
        return v
    if not isinstance(v, Mapping):
        raise _BadValueError("a field mapping")
    try:
        return ObsField(
            name=_str(v["name"]),
            start=_int(v["start"]),
            stop=_int(v["stop"]),
            unit=_str(v.get("unit", "")),
            doc=_str(v.get("doc", "")),
        )
    except (KeyError, _BadValueError):
        raise _BadValueError("a field mapping {name, start, stop, unit, doc}") from None


_FLOATS = _tuple_of(_float, "numbers")

CHECKS: dict[str, Check] = {
    "env_id": _str,
    "task": _str,
    "algo": _str,
    "policy": _str,
    "obs_mode": _str,
    "obs_shape": _tuple_of(_int, "integers"),
    "obs_layout": _tuple_of(_obs_field, "fields {name, start, stop, unit, doc}"),
    "obs_keys": _opt(_tuple_of(_str, "strings")),
    "obs_key_sizes": _opt(_tuple_of(_int, "integers")),
    "action_dim": _int,
    "n_actions": _opt(_int),
    "action_table": _opt(_tuple_of(_FLOATS, "rows of numbers")),
    "max_delta_rad": _float,
    "control_hz": _float,
    "spec_name": _str,
    "spec_fingerprint": _str,
    "spec": _mapping,
    "dr": _str,
    "dr_source": _str,
    "dr_ranges": _opt(_mapping),
    "seed": _int,
    "steps": _int,
    "training_seeds": _tuple_of(_int, "integers"),
    "env_kwargs": _mapping,
    "normalize": _bool,
    "vecnormalize": _opt(_mapping),
    "train": _mapping,
    "versions": _mapping,
    "created_utc": _str,
    "exported_from": _str,
    "export_format": _str,
    "note": _str,
    "adapted_from": _opt(_mapping),
    "obs_key_shapes": _opt(_tuple_of(_tuple_of(_int, "integers"), "shapes")),
}


def _build(cls: type[RunMeta], data: Mapping[str, Any], where: str, source: str) -> RunMeta:
    known = set(CHECKS) | {"format"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise MetaError(f"{where}: unknown field(s) {unknown}")
    kwargs: dict[str, Any] = {}
    for f in fields(cls):
        if f.name == "source":
            continue
        if f.name not in data:
            if f.name in OPTIONAL_FIELDS:
                continue
            raise MetaError(f"{where} lacks field {f.name!r}")
        try:
            kwargs[f.name] = CHECKS[f.name](data[f.name])
        except _BadValueError as bad:
            raise MetaError(
                f"{where}: field {f.name!r} must be {bad.expected}, got {_short(data[f.name])}"
            ) from None
    return cls(**kwargs, source=source)


def _short(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def _plain(v: Any) -> Any:
    """Tuples to lists and ObsFields to mappings, recursively: the JSON form."""
    if isinstance(v, ObsField):
        return {"name": v.name, "start": v.start, "stop": v.stop, "unit": v.unit, "doc": v.doc}
    if isinstance(v, list | tuple):
        return [_plain(x) for x in v]
    if isinstance(v, Mapping):
        return {k: _plain(x) for k, x in v.items()}
    return v


# ---- older formats ---------------------------------------------------------------------------
# config.json keys of format 1 that only described a gym space in words; the typed record derives
# the same facts from obs_shape/action_dim/n_actions.
_V1_DROPPED = ("observation_space", "action_space")


def _task_of(env_id: str) -> str:
    """The task of a registered env id (format 1 did not record it); "" when it has none."""
    from sim2real.env_table import task_of

    try:
        return task_of(env_id)
    except UnknownNameError:
        return ""


def _from_run_config_v1(data: Mapping[str, Any]) -> dict[str, Any]:
    """A run directory's ``config.json`` of format 1: the same keys, less ``task``."""
    d = {k: v for k, v in data.items() if k not in _V1_DROPPED}
    if "run_dir_note" in d:
        d["note"] = d.pop("run_dir_note")
    d.setdefault("task", _task_of(str(d.get("env_id", ""))))
    spec = d.get("spec")
    d.setdefault("spec_name", str(spec.get("name", "")) if isinstance(spec, Mapping) else "")
    d.setdefault("dr_source", d.get("dr", ""))
    d.setdefault("dr_ranges", None)
    d.setdefault("obs_mode", "state")
    d.setdefault("obs_shape", [])
    d.setdefault("obs_keys", None)
    d.setdefault("obs_key_sizes", None)
    d.setdefault("action_dim", 0)
    d.setdefault("n_actions", None)
    d.setdefault("action_table", None)
    d.setdefault("control_hz", 20.0)
    d.setdefault("max_delta_rad", 0.1)
    d.setdefault("policy", "")
    d.setdefault("normalize", True)
    d.setdefault("vecnormalize", None)
    d.setdefault("env_kwargs", {})
    d.setdefault("train", {})
    d.setdefault("versions", {})
    d.setdefault("created_utc", "")
    d["format"] = FORMAT
    return d


def _from_policy_meta_v1(data: Mapping[str, Any]) -> dict[str, Any]:
    """The ``PolicyMeta`` JSON exported policies embedded before format 2 (the shipped ones
    among them): flat fields plus an untyped ``extra`` holding the spec, DR ranges, env kwargs,
    training seeds and where it was exported from."""
    extra = data.get("extra")
    if not isinstance(extra, Mapping):
        raise MetaError("policy metadata of format 1: 'extra' is not a mapping")
    d = {k: v for k, v in data.items() if k not in ("extra", "source")}
    spec = extra.get("spec", {})
    train = {"env_id": d.get("env_id"), "algo": d.get("algo"), "dr": d.get("dr")}
    seeds = extra.get("training_seeds", [])
    ints = isinstance(seeds, list) and seeds and all(isinstance(x, int) for x in seeds)
    first_seed = min(seeds) if ints else 0  # segment 0's first env resets with the run's seed
    d.update(
        format=1,
        spec=spec,
        dr_ranges=extra.get("dr_ranges"),
        env_kwargs=extra.get("env_kwargs", {}),
        training_seeds=seeds,
        exported_from=extra.get("exported_from", ""),
        export_format=extra.get("format", ""),
        seed=first_seed,
        steps=0,  # not recorded before format 2
        train=train,
    )
    return d
