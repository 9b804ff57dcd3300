"""The format registry: every registered format round-trips a program, files load by suffix,
and the export package imports nothing from ``train`` or ``evaluate``."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sim2real.errors import UnknownNameError
from sim2real.export import FORMATS, PolicyMeta, load_policy
from sim2real.export.formats import get_format

REPO = Path(__file__).resolve().parents[3]
EXPORT_MODULES = sorted(
    p.stem for p in (REPO / "sim2real" / "export").glob("*.py") if p.stem != "__init__"
)


def _meta() -> PolicyMeta:
    return PolicyMeta(
        env_id="Arm3Reach-v0",
        algo="ppo",
        dr="none",
        spec_name="arm3",
        spec_fingerprint="0" * 16,
        obs_shape=(4,),
        action_dim=2,
    )


@pytest.mark.parametrize("name", sorted(FORMATS))
def test_every_format_round_trips_a_program(tmp_path: Path, name: str) -> None:
    rng = np.random.default_rng(0)
    program = [
        {"op": "dense", "weight": rng.normal(size=(8, 4)).astype(np.float32),
         "bias": rng.normal(size=8).astype(np.float32)},
        {"op": "act", "fn": "tanh"},
        {"op": "dense", "weight": rng.normal(size=(2, 8)).astype(np.float32),
         "bias": np.zeros(2, np.float32)},
    ]  # fmt: skip
    fmt = FORMATS[name]
    path = fmt.save(tmp_path / f"p{fmt.suffix}", program, _meta())
    policy = load_policy(path)
    obs = rng.normal(size=(5, 4)).astype(np.float32)
    expected = np.tanh(obs @ program[0]["weight"].T + program[0]["bias"]) @ program[2]["weight"].T
    np.testing.assert_allclose(policy(obs), expected, atol=1e-5)
    assert policy.meta.env_id == "Arm3Reach-v0"


def test_unknown_format_and_suffix_name_the_choices(tmp_path: Path) -> None:
    with pytest.raises(UnknownNameError, match="'tflite'.*numpy.*onnx"):
        get_format("tflite")
    (tmp_path / "x.pt").write_bytes(b"")
    with pytest.raises(UnknownNameError, match=r"'\.pt'.*\.npz.*\.onnx.*<run dir>"):
        load_policy(tmp_path / "x.pt")


def test_export_never_imports_train_or_evaluate() -> None:
    code = (
        "import sys\n"
        + "".join(f"import sim2real.export.{m}\n" for m in EXPORT_MODULES)
        + "print(sorted(m for m in sys.modules if m.startswith(('sim2real.train', "
        "'sim2real.evaluate'))))"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    )
    assert out.stdout.strip() == "[]"
