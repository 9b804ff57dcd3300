"""The firmware's compiled-in limits, generated from the ArmSpec (+ joint calibration).

``limits.h`` is how the spec reaches the Arduino: joint limits, per-command step clamp and
slew-rate limit in µs of pulse, the park pose, the watchdog timings, and which servos have their
potentiometer wired to an analog input (``feedback: measured`` in the spec), with the two-point
map from that input's ADC counts to µs of pulse.

The pot map lives here, on the chip, not in the host's joint calibration: a hobby servo's own
control loop compares the pulse with that very potentiometer, so counts ↔ µs is a property of the
servo alone (linear, whatever horn or joint it drives). Mapped to µs on the chip, a measured
reading and a commanded one share the unit the host commands in: the joint calibration
(µs ↔ rad), the safety clamps and the tracking-error check apply to both unchanged, and the
limits CRC in PONG names the pot map a board was flashed with. The same numbers drive the
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
from hardware.spec import PWM_SPEC_PATH, ArmSpec, load_spec

HEADER_PATH = Path(__file__).with_name("arm3") / "src" / "limits.h"
MAX_ACTUATORS = 8
UNO_PWM_PINS = (3, 5, 6, 9, 10, 11)  # Servo-library pins on an Uno/Nano, by servo_id
UNO_ADC_CHANNELS = (0, 1, 2, 3, 4, 5)  # the potentiometer of servo_id i on analog input A<i>
NO_POT = 255  # the channel of a servo without a wired potentiometer: its reading is commanded
ADC_MAX_COUNTS = 1023  # 10-bit ADC
# ADC counts at pulse_min_us and pulse_max_us for a wiper that sweeps 1.0 V .. 4.0 V of the 5 V
# reference over the servo's travel: a nominal figure, measure yours (docs/hardware-guide.md)
NOMINAL_POT_COUNTS = (205, 819)


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
    # potentiometers: ADC channel per actuator (NO_POT: none, the reading is the output pulse)
    # and the counts read with the horn where pot_us_min and pot_us_max pulses put it
    pot_channel: tuple[int, ...] = ()
    pot_counts_min: tuple[int, ...] = ()
    pot_counts_max: tuple[int, ...] = ()
    pot_us_min: int = 500
    pot_us_max: int = 2500

    def __post_init__(self) -> None:
        n = len(self.names)
        if not self.pot_channel:  # no pots given: a bare PWM build
            object.__setattr__(self, "pot_channel", (NO_POT,) * n)
            object.__setattr__(self, "pot_counts_min", (NOMINAL_POT_COUNTS[0],) * n)
            object.__setattr__(self, "pot_counts_max", (NOMINAL_POT_COUNTS[1],) * n)
        if not 1 <= n <= MAX_ACTUATORS:
            raise SpecError(f"the firmware drives 1..{MAX_ACTUATORS} actuators, got {n}")
        for key in (
            "servo_ids",
            "lower_us",
            "upper_us",
            "park_us",
            "max_step_us",
            "slew_us_per_s",
            "pot_channel",
            "pot_counts_min",
            "pot_counts_max",
        ):
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
            ch, c0, c1 = self.pot_channel[i], self.pot_counts_min[i], self.pot_counts_max[i]
            if ch != NO_POT and not 0 <= ch <= 7:
                raise SpecError(f"joint {name}: ADC channel {ch} is not 0..7 (or {NO_POT}: none)")
            if not (0 <= c0 <= ADC_MAX_COUNTS and 0 <= c1 <= ADC_MAX_COUNTS) or c0 == c1:
                raise SpecError(
                    f"joint {name}: pot counts {c0}..{c1} must be two different values in "
                    f"0..{ADC_MAX_COUNTS}"
                )
        if not 0 < self.pot_us_min < self.pot_us_max <= 0xFFFF:
            raise SpecError(
                f"pot pulse range [{self.pot_us_min}, {self.pot_us_max}] us is empty or invalid"
            )
        if not 1 <= self.watchdog_ms <= 0xFFFF or not 0 <= self.hold_ms <= 0xFFFF:
            raise SpecError("watchdog and hold times must fit in 16 bits of ms")

    @property
    def n(self) -> int:
        return len(self.names)

    @property
    def measured_mask(self) -> int:
        """Bit i set: actuator i reads its potentiometer (the STATE frame's readings byte)."""
        return sum(1 << i for i, ch in enumerate(self.pot_channel) if ch != NO_POT)

    def pot_us(self, i: int, counts: int) -> int:
        """The pulse (µs) that puts the horn where actuator i's pot reads ``counts``: integer
        arithmetic exactly as on the chip (arm3_core.cpp ``Core::pot_us``)."""
        c0, c1, c = self.pot_counts_min[i], self.pot_counts_max[i], int(counts)
        if c1 < c0:  # a pot wired the other way round
            c0, c1, c = -c0, -c1, -c
        c = min(max(c, c0), c1)
        span = self.pot_us_max - self.pot_us_min
        return self.pot_us_min + ((c - c0) * span + (c1 - c0) // 2) // (c1 - c0)

    def pot_counts(self, i: int, us: float) -> int:
        """The ADC counts actuator i's pot reads with the horn at pulse ``us`` (the emulators'
        potentiometer: the inverse of ``pot_us``, rounded and clipped to the ADC's range)."""
        c0, c1 = self.pot_counts_min[i], self.pot_counts_max[i]
        frac = (us - self.pot_us_min) / (self.pot_us_max - self.pot_us_min)
        return int(min(max(round(c0 + frac * (c1 - c0)), 0), ADC_MAX_COUNTS))

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
        body += struct.pack("<HH", self.watchdog_ms, self.hold_ms)
        for i in range(self.n):
            body += struct.pack(
                "<BHH", self.pot_channel[i], self.pot_counts_min[i], self.pot_counts_max[i]
            )
        return body + struct.pack("<HH", self.pot_us_min, self.pot_us_max)

    @property
    def crc(self) -> int:
        return crc16(self.pack())


def firmware_limits(
    spec: ArmSpec,
    calibration: ArmCalibration | None = None,
    pot_counts: dict[str, tuple[int, int]] | None = None,
) -> FirmwareLimits:
    """Limits in µs for ``spec`` through ``calibration`` (nominal when None). Raises SpecError
    naming the joint when a limit falls outside the servo's pulse range. Actuators whose spec
    feedback is ``measured`` read their pot on analog input A<servo_id>, through ``pot_counts``
    ({name: (counts at pulse_min_us, counts at pulse_max_us)}, NOMINAL_POT_COUNTS otherwise)."""
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
    given = dict(pot_counts or {})
    unknown = sorted(set(given) - set(spec.actuator_names))
    if unknown:
        raise SpecError(
            f"pot counts name actuator(s) {unknown}; valid: {list(spec.actuator_names)}"
        )
    channels, counts = [], []
    for name, sid, measured in zip(
        spec.actuator_names, spec.actuator_ids, spec.actuator_measured, strict=True
    ):
        if not measured:
            channels.append(NO_POT)
        elif sid >= len(UNO_ADC_CHANNELS):
            raise SpecError(
                f"joint {name}: servo_id {sid} has no analog input for its potentiometer on an "
                f"Uno/Nano (ids 0..{len(UNO_ADC_CHANNELS) - 1} read A0..A5); "
                "declare it feedback: commanded"
            )
        else:
            channels.append(UNO_ADC_CHANNELS[sid])
        counts.append(tuple(int(c) for c in given.get(name, NOMINAL_POT_COUNTS)))
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
        pot_channel=tuple(channels),
        pot_counts_min=tuple(c[0] for c in counts),
        pot_counts_max=tuple(c[1] for c in counts),
        pot_us_min=cal.frame.unit_min,
        pot_us_max=cal.frame.unit_max,
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
        f"#define ARM3_POT_US_MIN {limits.pot_us_min}",
        f"#define ARM3_POT_US_MAX {limits.pot_us_max}",
        f"#define ARM3_NO_POT {NO_POT}",
        "",
        "// Actuators, in order: " + ", ".join(limits.names),
        _array("uint16_t", "ARM3_LOWER_US", limits.lower_us),
        _array("uint16_t", "ARM3_UPPER_US", limits.upper_us),
        _array("uint16_t", "ARM3_PARK_US", limits.park_us),
        _array("uint16_t", "ARM3_MAX_STEP_US", limits.max_step_us),
        _array("uint16_t", "ARM3_SLEW_US_PER_S", limits.slew_us_per_s),
        _array("uint8_t", "ARM3_SERVO_CHANNEL", limits.servo_ids),
        _array("uint8_t", "ARM3_SERVO_PIN", [UNO_PWM_PINS[s] for s in limits.servo_ids]),
        "// Potentiometers (spec feedback: measured): ADC channel (A0..A5), or ARM3_NO_POT: the",
        "// reading is the output pulse. Counts read with the horn where ARM3_POT_US_MIN/MAX put it.",
        _array("uint8_t", "ARM3_POT_CHANNEL", limits.pot_channel),
        _array("uint16_t", "ARM3_POT_COUNTS_MIN", limits.pot_counts_min),
        _array("uint16_t", "ARM3_POT_COUNTS_MAX", limits.pot_counts_max),
        "",
    ]
    return "\n".join(lines)


def write_limits_header(
    out: str | Path,
    spec: ArmSpec,
    calibration: ArmCalibration | None = None,
    source: str = "",
    pot_counts: dict[str, tuple[int, int]] | None = None,
) -> Path:
    """Validate everything first, then write atomically: a bad spec writes nothing."""
    limits = firmware_limits(spec, calibration, pot_counts)
    text = render_limits_header(limits, source or f"spec {spec.name}")
    path = Path(out)
    atomic_write_text(path, text)
    return path


def default_header_text() -> str:
    """What the committed limits.h must contain: the default hobby build (bare PWM servos, no
    pots read: hardware/specs/arm3_mg996r_pwm.yaml), nominal calibration. A board flashed
    without thinking then reports commanded readings and says so, instead of reading floating
    analog inputs as positions; a pot build is generated from a spec that declares them."""
    spec = load_spec(PWM_SPEC_PATH)
    return render_limits_header(
        firmware_limits(spec),
        f"spec {spec.name} (hardware/specs/{PWM_SPEC_PATH.name}), nominal calibration",
    )


def parse_pot_counts(items: Sequence[str]) -> dict[str, tuple[int, int]]:
    """``["elbow=190:840", ...]`` -> {name: (counts at pulse_min_us, counts at pulse_max_us)}."""
    out: dict[str, tuple[int, int]] = {}
    for item in items:
        name, _, rest = item.partition("=")
        lo, _, hi = rest.partition(":")
        try:
            out[name] = (int(lo), int(hi))
        except ValueError:
            raise SpecError(
                f"--pot {item!r} is not NAME=COUNTS_MIN:COUNTS_MAX (e.g. elbow=190:840)"
            ) from None
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="write the arm3 firmware limits.h from a spec")
    parser.add_argument("--spec", default=None, help="ArmSpec YAML (default: the shipped spec)")
    parser.add_argument("--calibration", default=None, help="joint calibration YAML (s2r)")
    parser.add_argument("--out", default=str(HEADER_PATH), help="where to write limits.h")
    parser.add_argument(
        "--pot",
        action="append",
        default=[],
        metavar="NAME=MIN:MAX",
        help="measured potentiometer counts at pulse_min_us and pulse_max_us (nominal "
        f"{NOMINAL_POT_COUNTS[0]}:{NOMINAL_POT_COUNTS[1]}); repeat per actuator",
    )
    args = parser.parse_args(argv)
    try:
        if args.spec is None and args.calibration is None and not args.pot:
            atomic_write_text(args.out, default_header_text())
        else:
            spec = load_spec(args.spec)
            cal = ArmCalibration.load(args.calibration) if args.calibration else None
            pots = parse_pot_counts(args.pot)
            write_limits_header(
                args.out, spec, cal, source=f"spec {args.spec or spec.name}", pot_counts=pots
            )
    except HardwareError as exc:
        print(f"gen-limits: error: {exc}", file=sys.stderr)
        return 2
    print(args.out)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
