"""ArmSpec: validation names the bad value; FK/IK agree; YAML round-trips."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hardware.errors import SpecError
from hardware.spec import DEFAULT_SPEC_PATH, PWM_SPEC_PATH, ArmSpec, load_spec

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


# ---- feedback kinds -----------------------------------------------------------------------------
# Shipped policies are pinned to these: a spec that says nothing about feedback (every reading
# measured) must keep the fingerprint it had before feedback kinds existed.
DEFAULT_FINGERPRINT = "cd34ecb3e3f5294a"


def test_feedback_defaults_to_measured_and_keeps_the_fingerprint() -> None:
    assert SPEC.actuator_feedback == ("measured",) * SPEC.n_actuators
    assert SPEC.actuator_measured.all()
    assert SPEC.fingerprint() == DEFAULT_FINGERPRINT
    d = SPEC.to_dict()
    assert all("feedback" not in j for j in d["joints"]) and "feedback" not in d["gripper"]
    # saying "measured" out loud changes nothing either
    explicit = ArmSpec.from_dict(
        {**d, "joints": [{**j, "feedback": "measured"} for j in d["joints"]]}
    )
    assert explicit == SPEC and explicit.fingerprint() == DEFAULT_FINGERPRINT


def test_the_pwm_build_reads_its_commands_and_has_its_own_fingerprint(tmp_path: Path) -> None:
    pwm = load_spec(PWM_SPEC_PATH)
    assert pwm.actuator_feedback == ("commanded",) * pwm.n_actuators
    assert not pwm.actuator_measured.any()
    # the same arm otherwise
    assert pwm.with_feedback("measured").to_dict() == {**SPEC.to_dict(), "name": pwm.name}
    assert pwm.fingerprint() != pwm.with_feedback("measured").fingerprint()
    # one commanded joint is enough to change it, and it round-trips through YAML
    one = SPEC.with_feedback({"gripper": "commanded"})
    assert one.actuator_measured.tolist() == [True, True, True, False]
    assert one.fingerprint() != SPEC.fingerprint()
    one.to_yaml(tmp_path / "one.yaml")
    again = ArmSpec.from_yaml(tmp_path / "one.yaml")
    assert again == one and again.fingerprint() == one.fingerprint()


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            "servo_id: 2",
            "servo_id: 2\n    feedback: guessed",
            "joint elbow: feedback 'guessed' is not one of commanded, measured",
        ),
        ("max_gap_m: 0.05", "max_gap_m: 0.05\n  feedback: 1", "gripper: feedback 1 is not one of"),
    ],
)
def test_bad_feedback_kinds_fail_in_one_line(
    tmp_path: Path, old: str, new: str, message: str
) -> None:
    path = _mutated(tmp_path, old, new)
    with pytest.raises(SpecError, match=message) as info:
        ArmSpec.from_yaml(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)
    with pytest.raises(SpecError, match=r"feedback names actuator\(s\) \['wrist'\]"):
        SPEC.with_feedback({"wrist": "measured"})


def test_every_protocol_has_a_reading_table_and_mismatches_are_named() -> None:
    from hardware.feedback import (
        READING_SOURCES,
        protocol_kinds,
        readings_mismatch,
        spec_protocol_problem,
    )
    from hardware.protocols import PROTOCOLS

    assert {s.protocol for s in READING_SOURCES if s.protocol} == set(PROTOCOLS)
    assert protocol_kinds("feetech") == ("measured",)
    assert protocol_kinds("maestro") == ("commanded",)
    assert protocol_kinds("s2r") == ("commanded", "measured")
    with pytest.raises(SpecError, match="no reading table for protocol 'dxl'"):
        protocol_kinds("dxl")
    pwm = load_spec(PWM_SPEC_PATH)
    assert spec_protocol_problem(pwm, "s2r") == "" == spec_protocol_problem(SPEC, "feetech")
    problem = spec_protocol_problem(SPEC, "maestro")
    assert "base_yaw (measured)" in problem and "reports commanded" in problem
    assert "cannot deliver" in spec_protocol_problem(pwm, "feetech")
    assert readings_mismatch(SPEC, np.ones(4, dtype=bool)) == ""
    why = readings_mismatch(SPEC, np.array([True, True, False, False]))
    assert "elbow reads commanded (spec: measured)" in why and "gripper" in why and "\n" not in why
