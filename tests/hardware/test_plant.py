"""Plants: files round-trip, bad ones are one-line errors, and an emulator built from a plant
moves and reads as the plant says, byte for byte over the pty (SerialArm on the user's spec)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hardware.errors import SpecError
from hardware.plant import PLANT_DIR, Plant, load_plant, plant_names
from hardware.serial_arm import SerialArm
from hardware.spec import ArmSpec

ROOT = Path(__file__).resolve().parents[2]
ENV = dict(os.environ, PYTHONPATH=str(ROOT))


def test_presets_load_mild_to_hard_and_fit_the_shipped_spec(spec: ArmSpec) -> None:
    assert plant_names() == ["hard", "mild", "moderate"]
    plants = [load_plant(n) for n in ("mild", "moderate", "hard")]
    for plant in plants:
        plant.check_against(spec)
    speeds = [p.spec.servo.max_speed_rad_s for p in plants]
    assert speeds == sorted(speeds, reverse=True) and speeds[0] < spec.servo.max_speed_rad_s
    droops = [p.droop_rad for p in plants]
    assert droops == sorted(droops) and droops[0] > 0
    hard = plants[-1]
    # issue 20's measured plant: half speed, twice the lag, +50 ms, 0.02 rad droop, 3-4 mm
    assert hard.spec.servo.max_speed_rad_s == pytest.approx(spec.servo.max_speed_rad_s / 2)
    assert hard.spec.servo.time_constant_s == pytest.approx(2 * spec.servo.time_constant_s)
    assert hard.command_latency_s == pytest.approx(0.05) and hard.droop_rad == pytest.approx(0.02)
    link_err = [
        abs(getattr(hard.spec.links, k) - getattr(spec.links, k))
        for k in ("upper_arm_m", "forearm_m")
    ]
    assert all(0.003 <= e <= 0.004 for e in link_err)
    assert hard.offsets_rad()[2] == pytest.approx(2 * np.pi / 25, abs=1e-4)  # one tooth of 25


@pytest.mark.parametrize("name", ["mild", "moderate", "hard"])
def test_every_figure_of_a_preset_has_a_comment(name: str) -> None:
    lines = (PLANT_DIR / f"{name}.yaml").read_text().splitlines()
    start = lines.index("plant:")
    figures = [ln for ln in lines[start + 1 :] if ":" in ln and not ln.strip().startswith("#")]
    figures = [ln for ln in figures if not ln.rstrip().endswith(":")]  # mapping headers
    assert figures and all("#" in ln for ln in figures)


def test_a_plant_round_trips(tmp_path: Path) -> None:
    for name in plant_names():
        plant = load_plant(name)
        path = tmp_path / f"{name}.yaml"
        plant.to_yaml(path)
        again = load_plant(path)
        assert again == plant
        assert again.spec.fingerprint() == plant.spec.fingerprint()
    bare = Plant.nominal(load_plant("mild").spec)
    bare.to_yaml(tmp_path / "bare.yaml")
    assert load_plant(tmp_path / "bare.yaml") == bare


def _mutated(tmp_path: Path, old: str, new: str) -> Path:
    text = (PLANT_DIR / "moderate.yaml").read_text()
    assert old in text
    path = tmp_path / "plant.yaml"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("    elbow: -0.02", "    wrist: -0.02", r"names joint 'wrist', which spec .* valid: \["),
        ("  droop_rad: 0.01", "  droop_rad: -0.01", r"plant.droop_rad must be >= 0, got -0.01"),
        (
            "  noise_rad: 0.002",
            "  noise_rad: lots",
            r"plant.noise_rad must be a number, got 'lots'",
        ),
        ("  noise_rad: 0.002", "  noise_rad: 0.002\n  sag: 1", r"unknown plant key\(s\) \['sag'\]"),
        ("    shoulder: 0.03", "    shoulder: .nan", r"joint_offset_rad.shoulder must be finite"),
        ("    shoulder: 0.03", "    shoulder: 2.0", r"shoulder 2.0 is more than pi/2"),
        ("  forearm_m: 0.118", "  forearm_m: -0.118", r"links.forearm_m must be > 0, got -0.118"),
        ("  joint_offset_rad:\n", "  joint_offset_rad: 0.1\n", r"must map joint names to rad"),
    ],
)
def test_bad_plant_files_are_one_line_errors_naming_file_key_and_value(
    tmp_path: Path, old: str, new: str, message: str
) -> None:
    path = _mutated(tmp_path, old, new)
    if old == "  joint_offset_rad:\n":  # drop the block under it, so only the scalar remains
        path.write_text(
            path.read_text().replace("    shoulder: 0.03", "").replace("    elbow: -0.02", "")
        )
    with pytest.raises(SpecError, match=message) as info:
        load_plant(path)
    text = str(info.value)
    assert "\n" not in text and text.startswith(str(path))


def test_missing_plant_and_unknown_preset(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match="does not exist"):
        load_plant(tmp_path / "nope.yaml")
    with pytest.raises(SpecError, match=r"presets: \['hard', 'mild', 'moderate'\]"):
        load_plant("brutal")


def test_check_against_a_spec_with_other_joints(spec: ArmSpec) -> None:
    plant = load_plant("mild")
    renamed = replace(spec, joints=(replace(spec.joints[0], name="yaw"), *spec.joints[1:]))
    with pytest.raises(SpecError, match=r"plant actuators \['base_yaw'.* do not match spec"):
        plant.check_against(renamed)
    flipped = replace(
        spec, joints=(spec.joints[0], replace(spec.joints[1], axis="-y"), spec.joints[2])
    )
    with pytest.raises(SpecError, match="joint axes"):
        plant.check_against(flipped)


@pytest.mark.parametrize("protocol", ["s2r", "feetech"])
def test_emulator_from_a_plant_reads_and_moves_offset_and_drooped(
    spec: ArmSpec, protocol: str
) -> None:
    """Over the pty with the user's (shipped) spec: the servos read what was commanded while the
    joints physically sit ``offset - droop`` away, and the dynamics are the plant's servos."""
    truth = replace(spec, servo=replace(spec.servo, max_speed_rad_s=5.0, time_constant_s=0.07))
    plant = Plant(truth, (("shoulder", 0.06), ("elbow", -0.1)), droop_rad=0.015)
    emu = plant.emulator(protocol)
    assert emu.servos.p.max_speed_rad_s[0] == 5.0 and emu.servos.p.time_constant_s == 0.07
    assert emu.servos.p.droop_rad[1] == -0.015 and emu.config.droop_rad == 0.015
    with emu, SerialArm(spec, emu.port, protocol) as arm:
        goal = spec.actuator_home_rad + np.array([0.2, 0.1, -0.1, 0.0])
        arm.move_to(goal)
        emu.sync()
        reading = arm.read_state().positions_rad
        physical = emu.true_positions_rad()
        quant = 3 * spec.servo.resolution_rad
        np.testing.assert_allclose(physical - reading, plant.offsets_rad(), atol=quant)
        sag = np.array([0.0, -0.015, -0.015, 0.0])
        band = spec.servo.deadband_rad + quant
        np.testing.assert_allclose(physical, goal + plant.offsets_rad() + sag, atol=band)
        np.testing.assert_allclose(plant.reading_from_physical(physical), reading, atol=quant)


def test_cli_emulate_serves_a_plant_and_refuses_mixed_flags(spec: ArmSpec, tmp_path: Path) -> None:
    link = tmp_path / "arm3"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "sim2real",
            "arm",
            "emulate",
            "--plant",
            "mild",
            "--link",
            str(link),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
        cwd=ROOT,
        preexec_fn=lambda: signal.signal(signal.SIGTERM, signal.SIG_DFL),
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == str(link)
        with SerialArm(spec, str(link), "s2r") as arm:
            state = arm.home()
            np.testing.assert_allclose(state.positions_rad, spec.actuator_home_rad, atol=0.13)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
    bad = subprocess.run(
        [sys.executable, "-m", "sim2real", "arm", "emulate", "--plant", "hard", "--droop-rad", "1"],
        capture_output=True,
        text=True,
        env=ENV,
        cwd=ROOT,
        timeout=60,
    )
    lines = [ln for ln in bad.stderr.splitlines() if ln.strip()]
    assert bad.returncode == 2 and len(lines) == 1 and "give them in the plant file" in lines[0]
