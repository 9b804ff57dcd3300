"""What each protocol and servo can tell the host about where a joint is.

A bus servo measures its horn; a PWM servo reports nothing, so a board driving one can only echo
the pulse it sent. The spec declares per actuator which kind its readings are
(``JointSpec.feedback``); this table says which kinds each protocol can deliver, and the two
checks below turn a disagreement into one line that names the joints.

    protocol   device                                   readings
    feetech    Feetech STS/SMS bus servo (STS3215)      measured  (magnetic encoder)
    (none)     Feetech SCS bus servo                    measured  (the servo's potentiometer)
    maestro    Pololu Maestro + PWM servos              commanded (its own output pulse)
    s2r        arm3 firmware + bare PWM servos          commanded (the slewed output pulse)
    s2r        arm3 firmware + potentiometer mod        measured  (the pot on an analog input)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hardware.errors import SpecError
from hardware.spec import FEEDBACK_KINDS, ArmSpec


@dataclass(frozen=True)
class ReadingSource:
    """One protocol + servo combination and the kind of reading it gives."""

    protocol: str  # the --protocol name; "" where no driver here speaks it yet
    device: str
    kind: str  # a key of FEEDBACK_KINDS
    how: str  # where the number comes from

    def __post_init__(self) -> None:
        if self.kind not in FEEDBACK_KINDS:
            raise SpecError(f"{self.device}: reading kind {self.kind!r} is not a feedback kind")


READING_SOURCES: tuple[ReadingSource, ...] = (
    ReadingSource(
        "feetech",
        "Feetech STS/SMS bus servo (STS3215)",
        "measured",
        "present position from the servo's 12-bit magnetic encoder, with speed and load",
    ),
    ReadingSource(
        "",
        "Feetech SCS bus servo",
        "measured",
        "present position from the servo's potentiometer (big-endian; no driver here yet)",
    ),
    ReadingSource(
        "maestro",
        "Pololu Maestro + PWM servos",
        "commanded",
        "GET_POSITION is the Maestro's own output pulse after its speed limit",
    ),
    ReadingSource(
        "s2r",
        "arm3 firmware + bare PWM servos",
        "commanded",
        "the firmware's slew-limited output pulse",
    ),
    ReadingSource(
        "s2r",
        "arm3 firmware + PWM servos with the potentiometer mod",
        "measured",
        "the servo's potentiometer wiper on an analog input, ADC counts mapped to µs on the chip",
    ),
)


def protocol_kinds(protocol: str) -> tuple[str, ...]:
    """The reading kinds ``protocol`` can deliver (sorted); raises SpecError for an unknown
    protocol, listing the known ones."""
    kinds = sorted({s.kind for s in READING_SOURCES if s.protocol == protocol})
    if not kinds:
        known = sorted({s.protocol for s in READING_SOURCES if s.protocol})
        raise SpecError(f"no reading table for protocol {protocol!r}; known: {known}")
    return tuple(kinds)


def spec_protocol_problem(spec: ArmSpec, protocol: str) -> str:
    """Why ``spec``'s declared kinds cannot come from ``protocol`` ("" when they can)."""
    can = protocol_kinds(protocol)
    wrong = [
        f"{name} ({kind})"
        for name, kind in zip(spec.actuator_names, spec.actuator_feedback, strict=True)
        if kind not in can
    ]
    if not wrong:
        return ""
    return (
        f"spec {spec.name!r} declares readings {', '.join(wrong)} that protocol {protocol!r} "
        f"cannot deliver (it reports {' or '.join(can)})"
    )


def readings_mismatch(spec: ArmSpec, measured: np.ndarray) -> str:
    """Why the device's reading kinds (``measured`` (n_actuators,) bool, from the wire) differ
    from what ``spec`` declares ("" when they agree): a policy trained on one kind would run on
    the other."""
    got = np.asarray(measured, dtype=bool)
    want = spec.actuator_measured
    if got.shape != want.shape:
        raise SpecError(f"measured must have shape {want.shape}, got {got.shape}")
    wrong = [
        f"{name} reads {'measured' if g else 'commanded'} (spec: {'measured' if w else 'commanded'})"
        for name, g, w in zip(spec.actuator_names, got, want, strict=True)
        if g != w
    ]
    return (
        ""
        if not wrong
        else f"the arm's readings differ from spec {spec.name!r}: " + "; ".join(wrong)
    )
