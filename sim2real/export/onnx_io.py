"""The exported program as an ONNX graph (opset 17, IR 8), and an onnxruntime ``Policy``.

The graph is built node by node from the same op list the numpy policy runs, so both exports
compute the same function; normalisation runs in float64 as VecNormalize does. The metadata JSON
rides in the model's ``metadata_props``. A program that ends in an argmax also outputs the
per-action scores it reads (``scores``), so parity checks can compare logits, not only actions.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from hardware.atomic import atomic_write_bytes
from sim2real.export.policy import Policy, PolicyError, PolicyMeta, meta_from_json
from sim2real.export.program import (
    IMAGE_LAYOUTS,
    SLOT_OPS,
    Op,
    score_program,
    validate_program,
)

OPSET = 17
IR_VERSION = 8  # onnxruntime >= 1.10 reads it: old builds on a Raspberry Pi too
META_KEY = "sim2real_meta"
INPUT, OUTPUT, SCORES = "obs", "action", "scores"


class _GraphBuilder:
    def __init__(self) -> None:
        self.nodes: list[Any] = []
        self.initializers: list[Any] = []
        self._n = 0

    def name(self, hint: str) -> str:
        self._n += 1
        return f"{hint}_{self._n}"

    def const(self, hint: str, value: np.ndarray) -> str:
        from onnx import numpy_helper

        n = self.name(hint)
        self.initializers.append(numpy_helper.from_array(np.asarray(value), n))
        return n

    def node(self, op_type: str, inputs: list[str], hint: str, **attrs: Any) -> str:
        from onnx import helper

        out = self.name(hint)
        self.nodes.append(helper.make_node(op_type, inputs, [out], name=out, **attrs))
        return out


def _normalize(g: _GraphBuilder, x: str, op: Op) -> str:
    from onnx import TensorProto

    xd = g.node("Cast", [x], "obs64", to=TensorProto.DOUBLE)
    y = g.node("Sub", [xd, g.const("mean", op["mean"].astype(np.float64))], "centred")
    y = g.node("Div", [y, g.const("std", op["std"].astype(np.float64))], "scaled")
    if op.get("clip") is not None:
        c = float(op["clip"])
        lo, hi = g.const("lo", np.array(-c, np.float64)), g.const("hi", np.array(c, np.float64))
        y = g.node("Clip", [y, lo, hi], "clipped")
    return g.node("Cast", [y], "obs32", to=TensorProto.FLOAT)


def _dense(g: _GraphBuilder, x: str, op: Op) -> str:
    w = g.const("W", op["weight"].astype(np.float32))
    b = g.const("b", op["bias"].astype(np.float32))
    return g.node("Gemm", [x, w, b], "dense", transB=1)


def _act(g: _GraphBuilder, x: str, op: Op) -> str:
    fn = op["fn"]
    if fn == "relu":
        return g.node("Relu", [x], "relu")
    if fn == "tanh":
        return g.node("Tanh", [x], "tanh")
    if fn == "elu":
        return g.node("Elu", [x], "elu", alpha=float(op.get("alpha", 1.0)))
    return g.node("LeakyRelu", [x], "lrelu", alpha=float(op.get("alpha", 0.01)))


def _clip(g: _GraphBuilder, x: str, op: Op) -> str:
    lo = g.const("low", op["low"].astype(np.float32))
    hi = g.const("high", op["high"].astype(np.float32))
    return g.node("Min", [g.node("Max", [x, lo], "max"), hi], "min")


def _affine(g: _GraphBuilder, x: str, op: Op) -> str:
    y = g.node("Mul", [x, g.const("scale", op["scale"].astype(np.float32))], "mul")
    return g.node("Add", [y, g.const("offset", op["offset"].astype(np.float32))], "add")


def _argmax_table(g: _GraphBuilder, x: str, op: Op) -> str:
    idx = g.node("ArgMax", [x], "argmax", axis=1, keepdims=0)
    return g.node("Gather", [g.const("table", op["table"].astype(np.float32)), idx], "gather")


def _image(g: _GraphBuilder, x: str, op: Op) -> str:
    layout = IMAGE_LAYOUTS[op["layout"]]
    c, h, w = (int(n) for n in op["shape"])
    shape = g.const("image_shape", np.array([-1, *layout.shape((c, h, w))], np.int64))
    y = g.node("Reshape", [x, shape], "pixels")
    if layout.perm != (0, 1, 2, 3):
        y = g.node("Transpose", [y], "nchw", perm=list(layout.perm))
    return g.node("Div", [y, g.const("divisor", np.array(op["divisor"], np.float32))], "scaled")


def _conv2d(g: _GraphBuilder, x: str, op: Op) -> str:
    weight = op["weight"].astype(np.float32)
    ph, pw = (int(v) for v in op["padding"])
    return g.node(
        "Conv",
        [x, g.const("W", weight), g.const("b", op["bias"].astype(np.float32))],
        "conv",
        kernel_shape=list(weight.shape[2:]),
        strides=[int(v) for v in op["stride"]],
        pads=[ph, pw, ph, pw],
    )


def _coord_concat(g: _GraphBuilder, x: str, op: Op) -> str:
    coords = op["coords"].astype(np.float32)
    batch = g.node("Shape", [x], "batch", start=0, end=1)
    shape = g.node(
        "Concat", [batch, g.const("coord_dims", np.array(coords.shape, np.int64))], "shape", axis=0
    )
    tiled = g.node("Expand", [g.const("coords", coords[None]), shape], "coords")
    return g.node("Concat", [x, tiled], "coordconv", axis=1)


def _keypoints(g: _GraphBuilder, x: str, op: Op) -> str:
    fmap = g.node("Reshape", [x, g.const("maps", np.array([0, 0, -1], np.int64))], "maps")
    t = g.const("temperature", np.asarray(op["temperature"], np.float32))
    attn = g.node("Softmax", [g.node("Div", [fmap, t], "tempered")], "attention", axis=2)
    coords_t = g.const("map_coords_t", np.ascontiguousarray(op["map_coords"].T, np.float32))
    points = g.node("MatMul", [attn, coords_t], "points")  # (n, C, 2)
    flat = g.const("flat", np.array([0, -1], np.int64))
    points = g.node("Reshape", [points, flat], "keypoints")
    presence = g.node(
        "ReduceMax", [g.node("Relu", [fmap], "relu")], "presence", axes=[2], keepdims=0
    )
    return g.node("Concat", [points, presence], "features", axis=1)


def _flatten(g: _GraphBuilder, x: str, op: Op) -> str:
    return g.node("Flatten", [x], "flatten", axis=1)


def _argmax(g: _GraphBuilder, x: str, op: Op) -> str:
    from onnx import TensorProto

    idx = g.node("ArgMax", [x], "argmax", axis=1, keepdims=1)
    return g.node("Cast", [idx], "index", to=TensorProto.FLOAT)


ONNX_OPS: dict[str, Callable[[_GraphBuilder, str, Op], str]] = {
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


def _columns(g: _GraphBuilder, slot: str, op: Op) -> str:
    start = g.const("start", np.array([int(op["start"])], np.int64))
    stop = g.const("stop", np.array([int(op["stop"])], np.int64))
    return g.node("Slice", [slot, start, stop, g.const("axis", np.array([1], np.int64))], "cols")


def _store(g: _GraphBuilder, x: str, op: Op, slots: dict[str, str]) -> str:
    slots[op["name"]] = x
    return x


def _load(g: _GraphBuilder, x: str, op: Op, slots: dict[str, str]) -> str:
    return _columns(g, slots[op["name"]], op)


def _append(g: _GraphBuilder, x: str, op: Op, slots: dict[str, str]) -> str:
    return g.node("Concat", [x, _columns(g, slots[op["name"]], op)], "appended", axis=1)


# ``program.SLOT_OPS`` in the graph: a slot is the name of the tensor stored in it.
ONNX_SLOT_OPS: dict[str, Callable[[_GraphBuilder, str, Op, dict[str, str]], str]] = {
    "store": _store,
    "load": _load,
    "append": _append,
}


def save_onnx(path: str | Path, program: list[Op], meta: PolicyMeta) -> Path:
    import onnx
    from onnx import TensorProto, helper

    validate_program(program, meta.source)
    g = _GraphBuilder()
    x = INPUT
    slots: dict[str, str] = {}
    scoring = score_program(program)
    scores_at = -1 if scoring is None else len(scoring)
    outputs = [helper.make_tensor_value_info(OUTPUT, TensorProto.FLOAT, ["batch", meta.action_dim])]
    for i, op in enumerate(program):
        if i == scores_at:  # the scores the final argmax reads
            g.nodes.append(helper.make_node("Identity", [x], [SCORES], name=SCORES))
            outputs.append(helper.make_tensor_value_info(SCORES, TensorProto.FLOAT, ["batch", "n"]))
        kind = op["op"]
        x = ONNX_SLOT_OPS[kind](g, x, op, slots) if kind in SLOT_OPS else ONNX_OPS[kind](g, x, op)
    g.nodes.append(helper.make_node("Identity", [x], [OUTPUT], name=OUTPUT))
    graph = helper.make_graph(
        g.nodes,
        "sim2real_policy",
        [helper.make_tensor_value_info(INPUT, TensorProto.FLOAT, ["batch", meta.flat_obs_dim])],
        outputs,
        initializer=g.initializers,
    )
    model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        producer_name="sim2real",
        ir_version=IR_VERSION,
    )
    helper.set_model_props(model, {META_KEY: meta.to_json()})
    onnx.checker.check_model(model)
    return atomic_write_bytes(path, model.SerializeToString())


class OnnxPolicy(Policy):
    """Runs an exported ``.onnx`` policy with onnxruntime on the CPU."""

    def __init__(self, path: str | Path) -> None:
        import onnxruntime as ort

        src = str(path)
        try:
            opts = ort.SessionOptions()
            opts.intra_op_num_threads = 1
            opts.inter_op_num_threads = 1
            self._session = ort.InferenceSession(src, opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise PolicyError(f"policy {src!r} is not a loadable ONNX model ({msg})") from None
        props = self._session.get_modelmeta().custom_metadata_map
        if META_KEY not in props:
            raise PolicyError(f"policy {src!r} is an ONNX model without sim2real metadata")
        self.meta = meta_from_json(props[META_KEY], src)
        self._has_scores = SCORES in {o.name for o in self._session.get_outputs()}

    @classmethod
    def load(cls, path: str | Path) -> OnnxPolicy:
        return cls(path)

    def _act(self, batch: np.ndarray) -> np.ndarray:
        x = np.ascontiguousarray(batch, dtype=np.float32).reshape(len(batch), -1)
        (out,) = self._session.run([OUTPUT], {INPUT: x})
        return np.asarray(out, dtype=np.float32)

    def _scores(self, batch: np.ndarray) -> np.ndarray | None:
        if not self._has_scores:
            return None
        x = np.ascontiguousarray(batch, dtype=np.float32).reshape(len(batch), -1)
        (out,) = self._session.run([SCORES], {INPUT: x})
        return np.asarray(out, dtype=np.float32)
