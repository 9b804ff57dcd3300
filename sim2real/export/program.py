"""A policy as a short list of numeric ops, and its numpy interpreter.

The exporter turns an SB3 policy into this list once; the ``.npz`` file stores it, the ONNX
writer translates it op by op, and ``NumpyPolicy`` runs it with numpy alone (a Raspberry Pi
needs nothing else). Ops::

    normalize  (x - mean) / std, then clip to ±clip      (VecNormalize, folded in)
    dense      x @ weight.T + bias                        (weight: (out, in))
    act        relu | tanh | elu | leaky_relu             (alpha for elu / leaky_relu)
    clip       per-dimension [low, high]                   (Gaussian policies' action clip)
    affine     x * scale + offset                          (squashed policies' unscale)
    argmax_table  table[argmax(x)]                         (DQN: Q-values → continuous action)
"""

from __future__ import annotations

import io
import json
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

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


OPS: dict[str, Callable[[np.ndarray, Op], np.ndarray]] = {
    "normalize": _normalize,
    "dense": _dense,
    "act": _act,
    "clip": _clip,
    "affine": _affine,
    "argmax_table": _argmax_table,
}


def run_program(program: list[Op], x: np.ndarray) -> np.ndarray:
    y = np.asarray(x, dtype=np.float32).reshape(len(x), -1)
    for op in program:
        y = OPS[op["op"]](y, op)
    return y.astype(np.float32)


def validate_program(program: list[Op], source: str) -> None:
    for i, op in enumerate(program):
        kind = op.get("op")
        if kind not in OPS:
            raise PolicyError(f"policy {source!r}: op {i} {kind!r} unknown; valid: {sorted(OPS)}")
        if kind == "act" and op.get("fn") not in ACTIVATIONS:
            raise PolicyError(
                f"policy {source!r}: activation {op.get('fn')!r} unknown; "
                f"valid: {sorted(ACTIVATIONS)}"
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
