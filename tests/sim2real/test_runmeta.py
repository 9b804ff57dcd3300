"""``RunMeta``, the one record of a run and an exported policy: it round-trips, reads the older
formats (a run directory of format 1, the metadata the shipped policies embed), and refuses a bad
record with one line that names the version or the field."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hardware.spec import ArmSpec
from sim2real import env_table
from sim2real.errors import RunDirError
from sim2real.export import PolicyError, load_policy
from sim2real.export.program import save_npz
from sim2real.policies import shipped
from sim2real.runmeta import FORMAT, MetaError, ObsField, RunMeta
from sim2real.train.rundir import RunDir

V1_CONFIG = Path(__file__).resolve().parents[1] / "data" / "run_config_v1.json"


@pytest.fixture
def v1_run(tmp_path: Path) -> RunDir:
    """A run directory written before ``RunMeta`` (format 1: the shipped reach-ppo run)."""
    rd = RunDir(tmp_path / "old-run")
    rd.path.mkdir()
    shutil.copy(V1_CONFIG, rd.config_path)
    return rd


def _with(rd: RunDir, **changes: Any) -> RunDir:
    data = json.loads(rd.config_path.read_text())
    data.update(changes)
    rd.config_path.write_text(json.dumps(data))
    return rd


def test_a_format_1_run_dir_loads_typed(v1_run: RunDir) -> None:
    meta = v1_run.read_meta()
    assert meta.env_id == "Sim2Real/Arm3Reach-v0" and meta.task == "reach"  # task: from the id
    assert meta.algo == "ppo" and meta.policy == "MlpPolicy" and meta.seed == 0
    assert meta.training_seeds == tuple(range(8)) and meta.steps == 600_000
    assert meta.obs_layout[0] == ObsField(
        "joint_pos", 0, 3, "rad", "servo readings (joints, then gripper)"
    )
    assert [f.name for f in meta.obs_layout][-1] == "prev_action"
    assert meta.obs_shape == (24,) and meta.action_dim == 3 and meta.max_delta_rad == 0.05
    assert meta.vecnormalize == {"norm_obs": True, "norm_obs_keys": None, "norm_reward": False}
    assert ArmSpec.from_dict(dict(meta.spec)).fingerprint() == meta.spec_fingerprint
    assert meta.source == str(v1_run.path)
    assert v1_run.read_config()["format"] == FORMAT  # the dict view is the current format


def test_a_record_round_trips_through_a_run_dir(v1_run: RunDir, tmp_path: Path) -> None:
    meta = replace(v1_run.read_meta(), note="copied", adapted_from={"policy": "reach-ppo"})
    rd = RunDir(tmp_path / "new-run")
    rd.path.mkdir()
    rd.write_meta(meta)
    again = rd.read_meta()
    assert again == meta and again.source == str(rd.path)
    written = json.loads(rd.config_path.read_text())
    assert written["format"] == FORMAT and "source" not in written  # no machine path written
    assert RunMeta.from_json(meta.to_json()) == meta
    assert isinstance(again.obs_layout[0], ObsField) and isinstance(again.training_seeds, tuple)


@pytest.mark.parametrize("name", sorted(shipped()))
def test_every_shipped_policy_metadata_loads(name: str) -> None:
    """The shipped files embed the pre-RunMeta ``PolicyMeta`` JSON: it must keep loading."""
    meta, ship = load_policy(name).meta, shipped()[name]
    assert meta.env_id == ship.env_id
    # an arm task's card names the run's task; a sim-only env's (Kuka) names what it does
    assert meta.task == (ship.task if ship.task in env_table.DEPLOY_CONTRACTS else "")
    assert meta.export_format == "onnx" and meta.exported_from
    assert ArmSpec.from_dict(dict(meta.spec)).fingerprint() == meta.spec_fingerprint
    assert meta.training_seeds and meta.seed == min(meta.training_seeds)
    if meta.obs_keys is None:
        assert sum(f.size for f in meta.obs_layout) == meta.flat_obs_dim
    else:  # a frame beside proprioception, whose fields the state layout names
        sizes = dict(zip(meta.obs_keys, meta.obs_key_sizes or (), strict=True))
        layout = {f.name: f.size for f in meta.obs_layout}
        assert sum(layout[n] for n in meta.env_kwargs["proprio"]) == sizes["proprio"]
        assert sum(sizes.values()) == meta.flat_obs_dim and meta.obs_key_shapes is not None
    assert RunMeta.from_dict(meta.to_dict()) == meta  # and it writes as the current format


@pytest.mark.parametrize("version", [0, 3, "2", None, True])
def test_an_unknown_format_is_one_line_naming_it(v1_run: RunDir, version: Any) -> None:
    with pytest.raises(RunDirError) as err:
        _with(v1_run, format=version).read_meta()
    msg = str(err.value)
    assert "\n" not in msg and str(v1_run.path) in msg
    assert f"format {version!r}" in msg and "reads formats 1, 2" in msg


@pytest.mark.parametrize(
    ("field", "value", "expected"),
    [
        ("seed", "zero", "an integer"),
        ("seed", True, "an integer"),
        ("max_delta_rad", "0.05", "a number"),
        ("training_seeds", [0, "1"], "a list of integers"),
        ("obs_layout", [{"name": "joint_pos"}], "a list of fields"),
        ("obs_shape", 24, "a list of integers"),
        ("spec", [], "a mapping"),
        ("normalize", 1, "true or false"),
        ("env_id", None, "a string"),
    ],
)
def test_a_field_of_the_wrong_type_is_one_line_naming_it(
    v1_run: RunDir, field: str, value: Any, expected: str
) -> None:
    with pytest.raises(RunDirError) as err:
        _with(v1_run, **{field: value}).read_meta()
    msg = str(err.value)
    assert "\n" not in msg and f"field {field!r} must be {expected}" in msg, msg


def test_a_missing_or_unknown_field_is_one_line(v1_run: RunDir, tmp_path: Path) -> None:
    current = v1_run.read_meta().to_dict()
    del current["task"]
    with pytest.raises(MetaError, match=r"^metadata of 'x' lacks field 'task'$"):
        RunMeta.from_dict(current, source="x")
    with pytest.raises(MetaError, match=r"unknown field\(s\) \['colour'\]"):
        RunMeta.from_dict({**v1_run.read_meta().to_dict(), "colour": "red"})
    rd = RunDir(tmp_path / "bad")
    rd.path.mkdir()
    with pytest.raises(RunDirError, match="field 'steps' must be an integer"):
        rd.write_config({**v1_run.read_config(), "steps": 1.5})  # checked before it is written
    assert not rd.config_path.exists()


def test_a_policy_file_with_bad_metadata_is_one_policy_error(tmp_path: Path) -> None:
    meta = load_policy("reach-ppo").meta
    program = [
        {"op": "dense", "weight": np.zeros((3, 24), np.float32), "bias": np.zeros(3, np.float32)}
    ]
    good = save_npz(tmp_path / "good.npz", program, meta)
    assert load_policy(good).meta == meta
    bad = replace(meta, seed="zero")  # type: ignore[arg-type]
    path = save_npz(tmp_path / "bad.npz", program, bad)
    with pytest.raises(PolicyError) as err:
        load_policy(path)
    assert "\n" not in str(err.value) and "field 'seed' must be an integer" in str(err.value)
