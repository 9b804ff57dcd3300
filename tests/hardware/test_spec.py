"""ArmSpec: validation names the bad value; FK/IK agree; YAML round-trips."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hardware.errors import SpecError
from hardware.spec import DEFAULT_SPEC_PATH, ArmSpec, load_spec

SPEC = load_spec()


def _mutated(tmp_path: Path, old: str, new: str) -> Path:
    text = DEFAULT_SPEC_PATH.read_text()
    assert old in text
    path = tmp_path / "spec.yaml"
    path.write_text(text.replace(old, new, 1))
    return path


def test_default_spec_loads_with_derived_actuator_vectors() -> None:
    assert SPEC.joint_names == ("base_yaw", "shoulder", "elbow")
    assert SPEC.actuator_names[-1] == "gripper" and SPEC.n_actuators == 4
    assert np.all(SPEC.actuator_lower_rad < SPEC.actuator_upper_rad)
    assert np.all((SPEC.home_rad >= SPEC.lower_rad) & (SPEC.home_rad <= SPEC.upper_rad))


def test_ik_inverts_fk_across_the_joint_space() -> None:
    rng = np.random.default_rng(0)
    for _ in range(2000):
        q = rng.uniform(SPEC.lower_rad, SPEC.upper_rad)
        p = SPEC.forward_kinematics(q)
        q2 = SPEC.inverse_kinematics(p)
        assert q2 is not None
        np.testing.assert_allclose(SPEC.forward_kinematics(q2), p, atol=1e-9)
    assert SPEC.inverse_kinematics(np.array([1.0, 0.0, 0.1])) is None  # out of reach


def test_to_yaml_round_trips_exactly(tmp_path: Path) -> None:
    path = tmp_path / "copy.yaml"
    SPEC.to_yaml(path)
    again = ArmSpec.from_yaml(path)
    assert again == SPEC and again.fingerprint() == SPEC.fingerprint()


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("lower_rad: -0.5", "lower_rad: 1.5", r"joint shoulder: lower_rad \(1.5\) must be below"),
        ("axis: z", "axis: q", "axis 'q' is not one of"),
        ("axis: z", "axis: y", "does not fit the yaw-pitch-pitch topology"),
        ("upper_arm_m: 0.12", "upper_arm_m: -0.12", r"links.upper_arm_m must be > 0, got -0.12"),
        ("servo_id: 2", "servo_id: 1", r"servo ids must be unique, got \[0, 1, 1, 3\]"),
        ("lower_rad: -1.57", "lower_rad: -2.5", "more than the servo range"),
        ("max_step_rad: 0.25", "max_step_rad: .nan", "safety.max_step_rad must be finite"),
        ("name: arm3-mg996r", "name: arm3\ncolour: red", r"unknown key\(s\) \['colour'\]"),
        ("  upper_arm_m: 0.12", "  upper_arm_m: [0.12", r"flow sequence opened on line \d+"),
    ],
)
def test_bad_specs_fail_with_one_line_naming_the_value(
    tmp_path: Path, old: str, new: str, message: str
) -> None:
    path = _mutated(tmp_path, old, new)
    with pytest.raises(SpecError, match=message) as info:
        ArmSpec.from_yaml(path)
    assert "\n" not in str(info.value)
    assert str(path) in str(info.value)


def test_missing_spec_file_is_named() -> None:
    with pytest.raises(SpecError, match="no such file: 'nowhere.yaml'"):
        load_spec("nowhere.yaml")
