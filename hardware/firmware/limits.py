"""The firmware's compiled-in limits, generated from the ArmSpec (+ joint calibration).

``limits.h`` is how the spec reaches the Arduino: joint limits, per-command step clamp and
slew-rate limit in µs of pulse, the park pose, and the watchdog timings. The same numbers drive the
Python firmware model in the emulator, and a CRC over them lets the host see which limits a board
was flashed with (PONG reply).

Usage: ``sim2real arm gen-limits --spec SPEC.yaml [--calibration CAL.yaml] --out limits.h``
(or ``python -m hardware.firmware.limits``).
"""

from __future__ import annotations

import argparse
import struct
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hardware.atomic import atomic_write_text
from hardware.errors import HardwareError, SpecError
from hardware.joint_calibration import ArmCalibration, nominal_calibration
from hardware.protocols.s2r import S2RProtocol, crc16
from hardware.spec import ArmSpec, load_spec

HEADER_PATH = Path(__file__).with_name("arm3") / "src" / "limits.h"
MAX_ACTUATORS = 8
UNO_PWM_PINS = (3, 5, 6, 9, 10, 11)  # Servo-library pins on an Uno/Nano, by servo_id


@dataclass(frozen=True)
class FirmwareLimits:
    """Everything the firmware enforces, in integer µs and ms."""

    names: tuple[str, ...]
    servo_ids: tuple[int, ...]
    lower_us: tuple[int, ...]
    upper_us: tuple[int, ...]
    park_us: tuple[int, ...]
    max_step_us: tuple[int, ...]  # largest change of a target per SET_TARGETS frame
    slew_us_per_s: tuple[int, ...]  # output slew-rate limit
    watchdog_ms: int
    hold_ms: int

    def __post_init__(self) -> None:
        n = len(self.names)
        if not 1 <= n <= MAX_ACTUATORS:
            raise SpecError(f"the firmware drives 1..{MAX_ACTUATORS} actuators, got {n}")
        for key in ("servo_ids", "lower_us", "upper_us", "park_us", "max_step_us", "slew_us_per_s"):
            if len(getattr(self, key)) != n:
                raise SpecError(f"{key} has {len(getattr(self, key))} values, expected {n}")
        for i, name in enumerate(self.names):
            lo, hi, park = self.lower_us[i], self.upper_us[i], self.park_us[i]
            if not 0 < lo < hi <= 0xFFFF:
                raise SpecError(
                    f"joint {name}: firmware limits [{lo}, {hi}] us are empty or invalid"
                )
            if not lo <= park <= hi:
                raise SpecError(f"joint {name}: park {park} us is outside [{lo}, {hi}] us")
            if self.max_step_us[i] < 1 or self.slew_us_per_s[i] < 1:
                raise SpecError(f"joint {name}: step and slew limits must be >= 1")
        if not 1 <= self.watchdog_ms <= 0xFFFF or not 0 <= self.hold_ms <= 0xFFFF:
            raise SpecError("watchdog and hold times must fit in 16 bits of ms")

    @property
    def n(self) -> int:
        return len(self.names)

    def pack(self) -> bytes:
        """Canonical bytes the limits CRC is computed over (the C++ test recomputes it)."""
        body = bytes((self.n,))
        for i in range(self.n):
            body += struct.pack(
                "<HHHHH",
                self.lower_us[i],
                self.upper_us[i],
                self.park_us[i],
                self.max_step_us[i],
                self.slew_us_per_s[i],
            )
        return body + struct.pack("<HH", self.watchdog_ms, self.hold_ms)

    @property
    def crc(self) -> int:
        return crc16(self.pack())


def firmware_limits(spec: ArmSpec, calibration: ArmCalibration | None = None) -> FirmwareLimits:
    """Limits in µs for ``spec`` through ``calibration`` (nominal when None). Raises SpecError
    naming the joint when a limit falls outside the servo's pulse range."""
    frame = S2RProtocol.unit_frame(spec)
    cal = calibration or nominal_calibration(spec, S2RProtocol.name, frame)
    cal.check_protocol(S2RProtocol.name, frame)
    lo, hi = cal.unit_limits(spec)
    park = np.clip(cal.to_units(spec.actuator_park_rad), lo, hi)
    step = cal.max_step_units(spec.safety.max_step_rad)
    speeds = [spec.servo.max_speed_rad_s] * spec.n_joints
    if spec.gripper is not None:
        speeds.append(spec.gripper.max_speed_rad_s)
    slew = np.floor(np.array(speeds) * cal.scale_units_per_rad).astype(int)
    return FirmwareLimits(
        names=spec.actuator_names,
        servo_ids=spec.actuator_ids,
        lower_us=tuple(int(v) for v in lo),
        upper_us=tuple(int(v) for v in hi),
        park_us=tuple(int(v) for v in park),
        max_step_us=tuple(int(v) for v in step),
        slew_us_per_s=tuple(int(v) for v in slew),
        watchdog_ms=round(spec.safety.watchdog_timeout_s * 1000),
        hold_ms=round(spec.safety.hold_before_disable_s * 1000),
    )


def _array(ctype: str, name: str, values: Sequence[int]) -> str:
    return (
        f"static const {ctype} {name}[ARM3_N_ACTUATORS] = {{{', '.join(str(v) for v in values)}}};"
    )


def render_limits_header(limits: FirmwareLimits, source: str) -> str:
    """The C header text; deterministic, so a test can compare it with the committed file."""
    for sid in limits.servo_ids:
        if sid >= len(UNO_PWM_PINS):
            raise SpecError(
                f"servo_id {sid} has no PWM pin on an Uno/Nano (ids 0..{len(UNO_PWM_PINS) - 1} map "
                f"to pins {list(UNO_PWM_PINS)}); use the PCA9685 build for more channels"
            )
    lines = [
        "// Generated from the ArmSpec by `sim2real arm gen-limits` -- do not edit by hand.",
        f"// Source: {source}",
        "// Units: pulse widths in microseconds, times in milliseconds.",
        "#pragma once",
        "#include <stdint.h>",
        "",
        f"#define ARM3_N_ACTUATORS {limits.n}",
        f"#define ARM3_WATCHDOG_MS {limits.watchdog_ms}",
        f"#define ARM3_HOLD_MS {limits.hold_ms}",
        f"#define ARM3_LIMITS_CRC 0x{limits.crc:04X}",
        "",
        "// Actuators, in order: " + ", ".join(limits.names),
        _array("uint16_t", "ARM3_LOWER_US", limits.lower_us),
        _array("uint16_t", "ARM3_UPPER_US", limits.upper_us),
        _array("uint16_t", "ARM3_PARK_US", limits.park_us),
        _array("uint16_t", "ARM3_MAX_STEP_US", limits.max_step_us),
        _array("uint16_t", "ARM3_SLEW_US_PER_S", limits.slew_us_per_s),
        _array("uint8_t", "ARM3_SERVO_CHANNEL", limits.servo_ids),
        _array("uint8_t", "ARM3_SERVO_PIN", [UNO_PWM_PINS[s] for s in limits.servo_ids]),
        "",
    ]
    return "\n".join(lines)


def write_limits_header(
    out: str | Path, spec: ArmSpec, calibration: ArmCalibration | None = None, source: str = ""
) -> Path:
    """Validate everything first, then write atomically: a bad spec writes nothing."""
    limits = firmware_limits(spec, calibration)
    text = render_limits_header(limits, source or f"spec {spec.name}")
    path = Path(out)
    atomic_write_text(path, text)
    return path


def default_header_text() -> str:
    """What the committed limits.h must contain (the default spec, nominal calibration)."""
    spec = load_spec()
    return render_limits_header(
        firmware_limits(spec),
        f"spec {spec.name} (hardware/specs/arm3_mg996r.yaml), nominal calibration",
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="write the arm3 firmware limits.h from a spec")
    parser.add_argument("--spec", default=None, help="ArmSpec YAML (default: the shipped spec)")
    parser.add_argument("--calibration", default=None, help="joint calibration YAML (s2r)")
    parser.add_argument("--out", default=str(HEADER_PATH), help="where to write limits.h")
    args = parser.parse_args(argv)
    try:
        if args.spec is None and args.calibration is None:
            atomic_write_text(args.out, default_header_text())
        else:
            spec = load_spec(args.spec)
            cal = ArmCalibration.load(args.calibration) if args.calibration else None
            write_limits_header(args.out, spec, cal, source=f"spec {args.spec or spec.name}")
    except HardwareError as exc:
        print(f"gen-limits: error: {exc}", file=sys.stderr)
        return 2
    print(args.out)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
