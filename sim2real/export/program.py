"""A policy as a short list of numeric ops, and its numpy interpreter.

The exporter turns an SB3 policy into this list once; the ``.npz`` file stores it, the ONNX
writer translates it op by op, and ``NumpyPolicy`` runs it with numpy alone (a Raspberry Pi
needs nothing else). The list stays linear: each op maps one array to the next, (n, features)
or, between ``image`` and ``flatten``, (n, channels, height, width). Ops::

    normalize  (x - mean) / std, then clip to ±clip      (VecNormalize, folded in)
    dense      x @ weight.T + bias                        (weight: (out, in))
    act        relu | tanh | elu | leaky_relu             (alpha for elu / leaky_relu)
    clip       per-dimension [low, high]                   (Gaussian policies' action clip)
    affine     x * scale + offset                          (squashed policies' unscale)
    argmax_table  table[argmax(x)]                         (DQN: Q-values → continuous action)
    image      flat pixels → (n, C, H, W) / divisor        (SB3: HWC → CHW, uint8 / 255)
               layout: how the flat observation holds them ("chw" | "hwc"); shape: [C, H, W]
    conv2d     cross-correlation, weight (out, in, kh, kw), bias (out,), stride and zero
               padding [rows, cols]                        (torch ``Conv2d``)
    coord_concat  append coords (2, H, W) as channels      (CoordConv: x along W, y along H)
    keypoints  (n, C, h, w) → (n, 3C): (x, y) of each channel's softmax(map / temperature)
               over map_coords (2, h·w), then each channel's max(relu(map))  (spatial soft-argmax)
    flatten    (n, ...) → (n, -1), C-major like torch
    argmax     argmax(x) as a float32 (n, 1) index         (Discrete envs: the action)

A dict observation (an image beside proprioception) is one flat input too, its keys side by side
(``meta.obs_keys``). Three slot ops let the linear list read its parts: each names a slot, and
``load`` / ``append`` take the columns [start, stop) of it::

    store      slots[name] = x; x passes on unchanged
    load       x = slots[name][:, start:stop]
    append     x = concat(x, slots[name][:, start:stop])  (features beside the proprioception)

``argmax`` and ``argmax_table`` pick the action from per-action scores (logits or Q-values):
``SELECT_OPS``. A program ending in one also exposes those scores, for parity checks.
"""

from __future__ import annotations

import io
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from hardware.atomic import atomic_write_bytes
from sim2real.export.policy import Policy, PolicyError, PolicyMeta, meta_from_json

Op = dict[str, Any]
NPZ_FORMAT = 1


def _relu(x: np.ndarray, op: Op) -> np.ndarray:
    return np.maximum(x, np.float32(0.0))


def _tanh(x: np.ndarray, op: Op) -> np.ndarray:
    return np.tanh(x)


def _elu(x: np.ndarray, op: Op) -> np.ndarray:
    a = np.float32(op.get("alpha", 1.0))
    return np.where(x > 0, x, a * np.expm1(np.minimum(x, 0))).astype(np.float32)


def _leaky_relu(x: np.ndarray, op: Op) -> np.ndarray:
    a = np.float32(op.get("alpha", 0.01))
    return np.where(x > 0, x, a * x).astype(np.float32)


ACTIVATIONS: dict[str, Callable[[np.ndarray, Op], np.ndarray]] = {
    "relu": _relu,
    "tanh": _tanh,
    "elu": _elu,
    "leaky_relu": _leaky_relu,
}


def _normalize(x: np.ndarray, op: Op) -> np.ndarray:
    # float64 like VecNormalize, then float32 like the torch policy's input tensor
    y = (x.astype(np.float64) - op["mean"]) / op["std"]
    if op.get("clip") is not None:
        y = np.clip(y, -op["clip"], op["clip"])
    return y.astype(np.float32)


def _dense(x: np.ndarray, op: Op) -> np.ndarray:
    return x @ op["weight"].T + op["bias"]


def _act(x: np.ndarray, op: Op) -> np.ndarray:
    return ACTIVATIONS[op["fn"]](x, op)


def _clip(x: np.ndarray, op: Op) -> np.ndarray:
    return np.clip(x, op["low"], op["high"])


def _affine(x: np.ndarray, op: Op) -> np.ndarray:
    return x * op["scale"] + op["offset"]


def _argmax_table(x: np.ndarray, op: Op) -> np.ndarray:
    return op["table"][np.argmax(x, axis=1)]


@dataclass(frozen=True)
class ImageLayout:
    """How a flat observation holds an image: ``dims`` picks its axes from (C, H, W), ``perm``
    transposes the (n, *those axes) array to (n, C, H, W)."""

    dims: tuple[int, int, int]
    perm: tuple[int, int, int, int]

    def shape(self, chw: tuple[int, int, int]) -> tuple[int, int, int]:
        """The observation's own shape for an image the CNN reads as ``chw``."""
        return (chw[self.dims[0]], chw[self.dims[1]], chw[self.dims[2]])


# "chw" first: SB3 transposes an observation only when it is not already the CNN's shape.
IMAGE_LAYOUTS: dict[str, ImageLayout] = {
    "chw": ImageLayout((0, 1, 2), (0, 1, 2, 3)),
    "hwc": ImageLayout((1, 2, 0), (0, 3, 1, 2)),  # cameras and gymnasium; SB3's VecTransposeImage
}
CONV_CHUNK = 256  # observations per im2col block: bounds its memory on a long batch


def _image(x: np.ndarray, op: Op) -> np.ndarray:
    layout = IMAGE_LAYOUTS[op["layout"]]
    c, h, w = (int(n) for n in op["shape"])
    y = x.reshape(len(x), *layout.shape((c, h, w))).transpose(layout.perm)
    # a division, as torch's ``obs.float() / 255.0``: the same float32 for every pixel value
    return np.ascontiguousarray(y / np.float32(op["divisor"]), dtype=np.float32)


def _conv2d(x: np.ndarray, op: Op) -> np.ndarray:
    """im2col by strided windows (no copy) and one matrix product per block of observations."""
    weight = op["weight"]
    sh, sw = (int(v) for v in op["stride"])
    ph, pw = (int(v) for v in op["padding"])
    kh, kw = weight.shape[2:]
    if ph or pw:
        x = np.pad(x, ((0, 0), (0, 0), (ph, ph), (pw, pw)))
    out = []
    for start in range(0, max(len(x), 1), CONV_CHUNK):
        block = x[start : start + CONV_CHUNK]
        # windows over all four axes (one sample, one channel, kh, kw): a view, no copy
        cols = sliding_window_view(block, (1, 1, kh, kw))[:, :, ::sh, ::sw, 0, 0]
        # (n, in, out_h, out_w, kh, kw) · (out, in, kh, kw) → (n, out_h, out_w, out)
        out.append(np.tensordot(cols, weight, axes=([1, 4, 5], [1, 2, 3])))
    y = np.concatenate(out)
    return np.ascontiguousarray((y + op["bias"]).transpose(0, 3, 1, 2), dtype=np.float32)


def _coord_concat(x: np.ndarray, op: Op) -> np.ndarray:
    coords = np.broadcast_to(op["coords"], (len(x), *op["coords"].shape))
    return np.concatenate((x, coords), axis=1)


def _keypoints(x: np.ndarray, op: Op) -> np.ndarray:
    n, c = x.shape[:2]
    fmap = x.reshape(n, c, -1)
    z = fmap / op["temperature"]
    z = np.exp(z - z.max(axis=-1, keepdims=True))
    attn = z / z.sum(axis=-1, keepdims=True)
    points = (attn @ op["map_coords"].T).reshape(n, 2 * c)  # x, y of channel 0, then 1, ...
    presence = np.maximum(fmap, np.float32(0.0)).max(axis=-1)
    return np.concatenate((points, presence), axis=1).astype(np.float32)


def _flatten(x: np.ndarray, op: Op) -> np.ndarray:
    return x.reshape(len(x), -1)


def _argmax(x: np.ndarray, op: Op) -> np.ndarray:
    return np.argmax(x, axis=1).astype(np.float32)[:, None]


OPS: dict[str, Callable[[np.ndarray, Op], np.ndarray]] = {
    "normalize": _normalize,
    "dense": _dense,
    "act": _act,
    "clip": _clip,
    "affine": _affine,
    "argmax_table": _argmax_table,
    "image": _image,
    "conv2d": _conv2d,
    "coord_concat": _coord_concat,
    "keypoints": _keypoints,
    "flatten": _flatten,
    "argmax": _argmax,
}
SELECT_OPS: frozenset[str] = frozenset({"argmax", "argmax_table"})
# op → (its field that names a choice, the registry of valid choices)
CHOICES: dict[str, tuple[str, Mapping[str, Any]]] = {
    "act": ("fn", ACTIVATIONS),
    "image": ("layout", IMAGE_LAYOUTS),
}


def _store(x: np.ndarray, op: Op, slots: dict[str, np.ndarray]) -> np.ndarray:
    slots[op["name"]] = x
    return x


def _load(x: np.ndarray, op: Op, slots: dict[str, np.ndarray]) -> np.ndarray:
    return slots[op["name"]][:, int(op["start"]) : int(op["stop"])]


def _append(x: np.ndarray, op: Op, slots: dict[str, np.ndarray]) -> np.ndarray:
    part = slots[op["name"]][:, int(op["start"]) : int(op["stop"])]
    return np.concatenate((x, part), axis=1)


# Ops that also read or write the named slots (a dict observation's parts).
SLOT_OPS: dict[str, Callable[[np.ndarray, Op, dict[str, np.ndarray]], np.ndarray]] = {
    "store": _store,
    "load": _load,
    "append": _append,
}


def run_program(program: list[Op], x: np.ndarray) -> np.ndarray:
    y = np.asarray(x, dtype=np.float32).reshape(len(x), -1)
    slots: dict[str, np.ndarray] = {}
    for op in program:
        kind = op["op"]
        y = SLOT_OPS[kind](y, op, slots) if kind in SLOT_OPS else OPS[kind](y, op)
    return y.astype(np.float32)


def score_program(program: list[Op]) -> list[Op] | None:
    """The ops up to the per-action scores the final argmax reads; None if it has none."""
    if not program or program[-1]["op"] not in SELECT_OPS:
        return None
    return program[:-1]


def _check_slot_op(op: Op, i: int, stored: set[str], source: str) -> None:
    """A slot op names a slot (stored before it is read) and reads a non-empty column range:
    a bad one would otherwise slice silently to the wrong or no columns."""
    kind, name = op["op"], op.get("name")
    if not isinstance(name, str) or not name:
        raise PolicyError(f"policy {source!r}: op {i} {kind!r} has slot name {name!r}")
    if kind == "store":
        stored.add(name)
        return
    if name not in stored:
        raise PolicyError(f"policy {source!r}: op {i} {kind!r} reads slot {name!r} before a store")
    start, stop = op.get("start"), op.get("stop")
    if not (isinstance(start, int) and isinstance(stop, int) and 0 <= start < stop):
        raise PolicyError(
            f"policy {source!r}: op {i} {kind!r} reads columns [{start!r}, {stop!r}): "
            "need integers 0 <= start < stop"
        )


def validate_program(program: list[Op], source: str) -> None:
    stored: set[str] = set()
    for i, op in enumerate(program):
        kind = op.get("op")
        if kind not in OPS and kind not in SLOT_OPS:
            names = sorted({*OPS, *SLOT_OPS})
            raise PolicyError(f"policy {source!r}: op {i} {kind!r} unknown; valid: {names}")
        if kind in SLOT_OPS:
            _check_slot_op(op, i, stored, source)
        if kind in CHOICES:
            key, valid = CHOICES[kind]
            if op.get(key) not in valid:
                raise PolicyError(
                    f"policy {source!r}: op {i} {kind!r} has {key} {op.get(key)!r}; "
                    f"valid: {sorted(valid)}"
                )


# ---- .npz io: arrays by name plus a JSON description; loads with allow_pickle=False ----------
def save_npz(path: str | Path, program: list[Op], meta: PolicyMeta) -> Path:
    arrays: dict[str, np.ndarray] = {}
    described: list[dict[str, Any]] = []
    for i, op in enumerate(program):
        d: dict[str, Any] = {}
        for key, value in op.items():
            if isinstance(value, np.ndarray):
                name = f"op{i}_{key}"
                arrays[name] = value
                d[key] = {"array": name}
            else:
                d[key] = value
        described.append(d)
    header = {"format": NPZ_FORMAT, "program": described}
    buf = io.BytesIO()
    np.savez(
        buf, __program__=np.array(json.dumps(header)), __meta__=np.array(meta.to_json()), **arrays
    )
    return atomic_write_bytes(path, buf.getvalue())


def load_npz(path: str | Path) -> tuple[list[Op], PolicyMeta]:
    src = str(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            header = json.loads(str(z["__program__"]))
            meta = meta_from_json(str(z["__meta__"]), src)
            arrays = {k: z[k] for k in z.files if not k.startswith("__")}
    except (OSError, ValueError, KeyError) as exc:
        raise PolicyError(f"policy {src!r} is not a sim2real .npz policy ({exc})") from None
    if header.get("format") != NPZ_FORMAT:
        raise PolicyError(f"policy {src!r}: format {header.get('format')!r} is not {NPZ_FORMAT}")
    program: list[Op] = []
    for d in header["program"]:
        op: Op = {}
        for key, value in d.items():
            op[key] = arrays[value["array"]] if isinstance(value, Mapping) else value
        program.append(op)
    validate_program(program, src)
    return program, meta


class NumpyPolicy(Policy):
    """Runs an exported program with numpy alone."""

    def __init__(self, program: list[Op], meta: PolicyMeta) -> None:
        validate_program(program, meta.source)
        self.program = program
        self.meta = meta

    @classmethod
    def load(cls, path: str | Path) -> NumpyPolicy:
        return cls(*load_npz(path))

    def _act(self, batch: np.ndarray) -> np.ndarray:
        return run_program(self.program, batch)

    def _scores(self, batch: np.ndarray) -> np.ndarray | None:
        ops = score_program(self.program)
        return None if ops is None else run_program(ops, batch)
