"""Joint calibration: the rad <-> units map, inward-rounded limits, fitting from two poses,
atomic YAML per arm id, and one-line errors for corrupt files."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hardware.errors import CalibrationFileError, SpecError
from hardware.joint_calibration import (
    CALIBRATION_DIR_ENV,
    ArmCalibration,
    calibration_path,
    fit_joint,
    nominal_calibration,
    with_joints,
)
from hardware.protocols import PROTOCOLS
from hardware.spec import ArmSpec


def _nominal(spec: ArmSpec, protocol: str = "s2r") -> ArmCalibration:
    return nominal_calibration(spec, protocol, PROTOCOLS[protocol].unit_frame(spec), arm_id="lab1")


@settings(max_examples=100, deadline=None)
@given(
    offsets=st.lists(st.floats(1300, 1700), min_size=4, max_size=4),
    directions=st.lists(st.sampled_from([1, -1]), min_size=4, max_size=4),
    scales=st.lists(st.floats(500, 700), min_size=4, max_size=4),
    q=st.lists(st.floats(-1.2, 1.2), min_size=4, max_size=4),
)
def test_round_trip_and_inward_limits(
    spec: ArmSpec, offsets: list[float], directions: list[int], scales: list[float], q: list[float]
) -> None:
    cal = with_joints(_nominal(spec), offsets, directions, scales)
    qa = np.array(q)
    np.testing.assert_allclose(cal.from_units(cal.to_units_float(qa)), qa, atol=1e-12)
    # integer units are at most half a unit away (inside the servo's range; outside it, clipped)
    inside = (cal.to_units_float(qa) >= cal.frame.unit_min) & (
        cal.to_units_float(qa) <= cal.frame.unit_max
    )
    err = np.abs(cal.from_units(cal.to_units(qa)) - qa)
    assert np.all(err[inside] <= 0.5 / cal.scale_units_per_rad[inside] + 1e-12)
    assert np.all(cal.to_units(qa) >= cal.frame.unit_min) and np.all(
        cal.to_units(qa) <= cal.frame.unit_max
    )
    try:
        lo, hi = cal.unit_limits(spec)
    except SpecError:
        return  # this mounting puts a limit outside the servo range: refused, as it should be
    a, b = cal.from_units(lo), cal.from_units(hi)
    inside_lo, inside_hi = np.minimum(a, b), np.maximum(a, b)
    assert np.all(inside_lo >= spec.actuator_lower_rad - 1e-9)
    assert np.all(inside_hi <= spec.actuator_upper_rad + 1e-9)
    step = cal.max_step_units(spec.safety.max_step_rad)
    assert np.all(step / cal.scale_units_per_rad <= spec.safety.max_step_rad + 1e-12)


def test_limits_outside_the_servo_range_name_the_joint(spec: ArmSpec) -> None:
    cal = with_joints(_nominal(spec), scales_units_per_rad=[636.6, 636.6, 900.0, 636.6])
    with pytest.raises(SpecError, match=r"joint elbow: limits \[-0.9000, 1.4000\] rad map to"):
        cal.unit_limits(spec)


def test_fit_joint_recovers_offset_direction_and_scale() -> None:
    j = fit_joint("elbow", 1540.0, 1540.0 - 0.5 * 650.0, 0.5)
    assert (j.offset_units, j.direction, j.scale_units_per_rad) == (1540.0, -1, 650.0)
    with pytest.raises(CalibrationFileError, match="did not move"):
        fit_joint("elbow", 1500.0, 1500.0, 0.5)
    with pytest.raises(CalibrationFileError, match="non-zero"):
        fit_joint("elbow", 1500.0, 1600.0, 0.0)


def test_save_load_round_trip_and_pyyaml_agrees(spec: ArmSpec, tmp_path: Path) -> None:
    yaml = pytest.importorskip("yaml")
    cal = with_joints(_nominal(spec, "feetech"), [2000.5, 2100.0, 1990.25, 2048.0], [1, -1, 1, -1])
    path = cal.save(calibration_path("lab1", tmp_path))
    assert path == tmp_path / "lab1.yaml"
    assert ArmCalibration.load(path) == cal
    assert yaml.safe_load(path.read_text()) == cal.to_dict()
    assert [p.name for p in tmp_path.iterdir()] == ["lab1.yaml"]  # no temp files left behind


def test_calibration_dir_from_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(CALIBRATION_DIR_ENV, str(tmp_path))
    assert calibration_path("arm-2") == tmp_path / "arm-2.yaml"
    with pytest.raises(CalibrationFileError, match="arm id"):
        calibration_path("../etc/passwd")


def test_a_failed_save_leaves_the_old_file_intact(
    spec: ArmSpec, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    old = _nominal(spec)
    path = old.save(tmp_path / "lab1.yaml")
    before = path.read_text()

    def power_cut(fd: int) -> None:
        raise OSError("disk went away")

    monkeypatch.setattr(os, "fsync", power_cut)
    with pytest.raises(OSError):
        with_joints(old, offsets_units=[1400.0] * 4).save(path)
    assert path.read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["lab1.yaml"]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("arm_id: lab1\njoints: [\n", "corrupt calibration YAML"),
        ("arm_id: lab1\n\tprotocol: s2r\n", "corrupt calibration YAML.*tabs"),
        ("- 1\n- 2\n", "expected a mapping"),
        ("arm_id: lab1\nprotocol: s2r\n", r"missing key\(s\)"),
        (
            "arm_id: lab1\nprotocol: s2r\nunits: us\nunit_min: 500\nunit_max: 2500\nwat: 1\njoints:\n"
            "  - name: a\n",
            r"unknown key\(s\) \['wat'\]",
        ),
        (
            "arm_id: lab1\nprotocol: s2r\nunits: us\nunit_min: 500\nunit_max: 2500\njoints:\n"
            "  - name: base_yaw\n    offset_units: 1500.0\n    direction: 2\n    scale_units_per_rad: 636.6\n",
            "direction must be 1 or -1, got 2",
        ),
        (
            "arm_id: lab1\nprotocol: s2r\nunits: us\nunit_min: 500\nunit_max: 2500\njoints:\n"
            "  - name: base_yaw\n    offset_units: .nan\n    direction: 1\n    scale_units_per_rad: 636.6\n",
            "offset_units must be finite",
        ),
    ],
)
def test_corrupt_files_give_one_line_errors(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "lab1.yaml"
    path.write_text(text)
    with pytest.raises(CalibrationFileError, match=message) as info:
        ArmCalibration.load(path)
    assert "\n" not in str(info.value)
    assert str(path) in str(info.value)


def test_missing_file_and_wrong_joints(spec: ArmSpec, tmp_path: Path) -> None:
    with pytest.raises(CalibrationFileError, match="run `sim2real arm calibrate`"):
        ArmCalibration.load(tmp_path / "nope.yaml")
    cal = _nominal(spec)
    wrong = ArmCalibration(cal.arm_id, cal.protocol, cal.frame, cal.joints[:3])
    with pytest.raises(CalibrationFileError, match="has joints"):
        wrong.check_spec(spec)
