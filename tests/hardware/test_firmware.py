"""The arm3 firmware: its C++ core compiled with g++ and tested on the host, the same byte
streams replayed through the C++ core and the emulator's Python model (identical output required),
and the generated limits header kept in step with the spec."""

from __future__ import annotations

import random
import subprocess
from dataclasses import replace
from pathlib import Path

import pytest

from hardware.emulator.firmware import FirmwareCore
from hardware.errors import SpecError
from hardware.firmware.limits import (
    HEADER_PATH,
    default_header_text,
    firmware_limits,
    write_limits_header,
)
from hardware.protocols import s2r
from hardware.spec import PWM_SPEC_PATH, ArmSpec, load_spec


def test_core_host_tests_pass(firmware_build: dict[str, Path]) -> None:
    proc = subprocess.run([firmware_build["test_core"]], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "checks passed" in proc.stdout


def test_arduino_sketch_compiles_and_runs_on_stubs(firmware_build: dict[str, Path]) -> None:
    proc = subprocess.run(
        [firmware_build["test_sketch"]], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0, proc.stderr


def test_committed_limits_header_matches_the_spec() -> None:
    assert HEADER_PATH.read_text() == default_header_text(), (
        "hardware/firmware/arm3/src/limits.h is stale: run `python -m hardware.firmware.limits`"
    )


def test_limits_follow_the_spec(spec: ArmSpec) -> None:
    lim = firmware_limits(spec)
    assert lim.n == spec.n_actuators
    assert lim.watchdog_ms == 250 and lim.hold_ms == 500
    for i in range(lim.n):
        # inward rounding: the µs limits decode inside the rad limits
        us_per_rad = spec.servo.us_per_rad
        center = (spec.servo.pulse_min_us + spec.servo.pulse_max_us) / 2
        assert (lim.lower_us[i] - center) / us_per_rad >= spec.actuator_lower_rad[i] - 1e-12
        assert (lim.upper_us[i] - center) / us_per_rad <= spec.actuator_upper_rad[i] + 1e-12
        assert lim.max_step_us[i] / us_per_rad <= spec.safety.max_step_rad


def test_bad_spec_writes_no_header(spec: ArmSpec, tmp_path: Path) -> None:
    # a calibration whose scale maps the limits past the servo's pulse range
    from hardware.joint_calibration import nominal_calibration, with_joints
    from hardware.protocols.s2r import S2RProtocol

    nominal = nominal_calibration(spec, "s2r", S2RProtocol.unit_frame(spec))
    too_big = with_joints(nominal, scales_units_per_rad=[900.0] * spec.n_actuators)
    out = tmp_path / "limits.h"
    with pytest.raises(SpecError, match="base_yaw.*outside the servo range"):
        write_limits_header(out, spec, too_big)
    assert not out.exists() and list(tmp_path.iterdir()) == []
    assert spec.gripper is not None
    bad_ids = replace(spec, gripper=replace(spec.gripper, servo_id=9))
    with pytest.raises(SpecError, match="servo_id 9 has no analog input for its potentiometer"):
        write_limits_header(out, bad_ids)
    with pytest.raises(SpecError, match="no PWM pin"):
        write_limits_header(out, bad_ids.with_feedback({"gripper": "commanded"}))
    with pytest.raises(SpecError, match=r"pot counts name actuator\(s\) \['wrist'\]"):
        write_limits_header(out, spec, pot_counts={"wrist": (1, 2)})
    with pytest.raises(SpecError, match="joint elbow: pot counts 300..300 must be two different"):
        write_limits_header(out, spec, pot_counts={"elbow": (300, 300)})
    assert not out.exists()


# ---- C++ vs Python on identical byte streams ----------------------------------------------------
def _script(seed: int, limits_n: int) -> list[str]:
    """Random but protocol-shaped traffic: every message type, garbage, corruption, truncation,
    retransmissions, gaps, silences long enough to trip the watchdog, and potentiometers that
    move (including beyond their calibrated span)."""
    rng = random.Random(seed)
    lines: list[str] = []
    t = 0
    seq = 0

    def frame(msg: int, payload: bytes) -> bytes:
        nonlocal seq
        seq = (seq + 1) & 0xFF
        return s2r.encode_frame(seq, msg, payload)

    last = b""
    for _ in range(400):
        t += rng.choice([1, 2, 5, 10, 20, 50])
        kind = rng.random()
        if kind < 0.30:
            payload = b"".join(
                rng.randrange(300, 2700).to_bytes(2, "little") for _ in range(limits_n)
            )
            data = frame(s2r.SET_TARGETS, payload)
        elif kind < 0.34:
            data = frame(s2r.TORQUE, bytes((rng.choice([0, 1, 1, 1, 2]),)))
        elif kind < 0.38:  # torque on with start pulses (sometimes malformed)
            starts = [rng.randrange(300, 2700) for _ in range(limits_n)]
            data = frame(
                s2r.TORQUE,
                bytes((rng.choice([1, 1, 1, 0]),))
                + s2r.encode_targets(starts)[: rng.choice([8, 8, 3])],
            )
        elif kind < 0.46:
            data = frame(s2r.READ_STATE, b"")
        elif kind < 0.50:
            data = frame(s2r.PING, b"")
        elif kind < 0.53:
            data = frame(s2r.GET_STATS, b"")
        elif kind < 0.58:
            vals = []
            for _ in range(limits_n):
                lo = rng.randrange(400, 1500)
                vals += [lo, lo + rng.randrange(1, 1200), rng.randrange(0, 200)]
            data = frame(s2r.SET_LIMITS, b"".join(v.to_bytes(2, "little") for v in vals))
        elif kind < 0.62:
            data = frame(s2r.HEARTBEAT, b"")
        elif kind < 0.66:
            data = frame(
                rng.randrange(8, 0x7F), bytes(rng.randrange(256) for _ in range(rng.randrange(4)))
            )
        elif kind < 0.72:
            data = last  # a retransmission
        elif kind < 0.80:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 12)))  # garbage
        else:
            broken = bytearray(frame(s2r.SET_TARGETS, bytes(2 * limits_n)))
            broken[rng.randrange(len(broken))] ^= rng.randrange(1, 256)  # corrupted
            data = bytes(broken)
        if rng.random() < 0.1 and len(data) > 2:
            cut = rng.randrange(1, len(data))
            lines.append(f"R {t} {data[:cut].hex()}")
            t += rng.choice([0, 1, 15])  # sometimes longer than the inter-byte gap
            data = data[cut:]
        lines.append(f"R {t} {data.hex()}")
        last = data
        if rng.random() < 0.15:
            lines.append(f"A {rng.randrange(limits_n)} {rng.randrange(0, 1024)}")
        lines.append(f"T {t}")
        if rng.random() < 0.05:
            for _ in range(rng.randrange(1, 80)):  # silence: the watchdog may trip
                t += 10
                lines.append(f"T {t}")
                lines.append("S")  # catches the exact tick the watchdog holds and detaches
        lines.append("S")
    return lines


def _run_python(lines: list[str], spec: ArmSpec, boot_id: int) -> list[str]:
    core = FirmwareCore(firmware_limits(spec), boot_id, now_ms=0)
    n = spec.n_actuators
    out: list[str] = []
    for line in lines:
        parts = line.split()
        if parts[0] == "R":
            data = bytes.fromhex(parts[2]) if len(parts) > 2 else b""
            out += [f"TX {r.hex()}" for r in core.feed(data, int(parts[1]))]
        elif parts[0] == "A":
            core.set_pot(int(parts[1]), int(parts[2]))
        elif parts[0] == "T":
            core.tick(int(parts[1]))
        else:
            st = core.stats
            outs = " ".join(
                f"{core.output[i]}/{core.target[i]}/{core.position(i)}" for i in range(n)
            )
            counters = [
                st.rx_frames,
                st.crc_errors,
                st.header_errors,
                st.garbage_bytes,
                st.gap_resets,
                st.watchdog_trips,
                st.clamps,
                st.duplicates,
            ]
            out.append(
                f"ST {int(core.attached)} {int(core.holding)} {core.flags()} "
                f"{core.measured_mask()} {outs} | " + " ".join(str(c & 0xFFFF) for c in counters)
            )
    return out


@pytest.mark.parametrize(
    ("seed", "build"), [(1, "replay"), (2, "replay"), (3, "replay_pots"), (4, "replay_pots")]
)
def test_python_model_matches_cpp_core(
    firmware_build: dict[str, Path], spec: ArmSpec, seed: int, build: str
) -> None:
    """Both builds: bare PWM servos (the committed header, readings commanded) and every servo's
    potentiometer wired (the shipped spec's pot build, readings measured)."""
    build_spec = load_spec(PWM_SPEC_PATH) if build == "replay" else spec
    lines = _script(seed, spec.n_actuators)
    boot_id = 0x1000 + seed
    proc = subprocess.run(
        [firmware_build[build], str(boot_id)],
        input="\n".join(lines) + "\n",
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    cpp = proc.stdout.splitlines()
    py = _run_python(lines, build_spec, boot_id)
    assert len(cpp) == len(py)
    for k, (a, b) in enumerate(zip(cpp, py, strict=True)):
        assert a == b, f"line {k}: C++ {a!r} != Python {b!r}"
    # the script exercised what it is meant to: replies, clamps, watchdog, duplicates, errors
    last = py[-1].split("|")[1].split()
    rx, crc, _hdr, garbage, _gap, trips, clamps, dups = (int(v) for v in last)
    assert rx > 100 and crc > 0 and garbage > 0 and clamps > 0 and dups > 0
    assert trips > 0 or seed != 1
    assert any(x.startswith("TX ") and x[13:15] == "ff" for x in py)  # error replies happened
    mask = firmware_limits(build_spec).measured_mask
    assert mask == (0 if build == "replay" else 0b1111)
    states = [x for x in py if x.startswith("TX ") and x[13:15] in ("82", "83")]
    assert states and all(int(x[21:23], 16) == mask for x in states)  # the readings byte


def test_the_wiring_figure_draws(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    from hardware.firmware.wiring_figure import main

    out = tmp_path / "wiring.png"
    assert main([str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 20_000
