"""The arm3 sketch as the chip runs it: build it for the ATmega328P, report its size, and build
the simavr harness that runs the very same ``.elf``.

Everything goes through ``hardware/firmware/arm3/Makefile`` (``make avr``, ``make sim``); this
module finds the tools, serialises concurrent builds (pytest workers share one build folder) and
turns ``avr-size`` into numbers with a budget. ``python -m hardware.firmware.avr`` prints the
size report as one JSON line and fails when a budget is exceeded.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from hardware.errors import HardwareError
from hardware.firmware.limits import HEADER_PATH, firmware_limits, render_limits_header
from hardware.spec import ArmSpec

ARM3_DIR = Path(__file__).with_name("arm3")
BUILD_DIR = ARM3_DIR / "build"
ARDUINO_AVR = Path(os.environ.get("ARDUINO_AVR", "/usr/share/arduino/hardware/arduino/avr"))
SIMAVR_INCLUDE = Path("/usr/include/simavr/sim_avr.h")
APT_PACKAGES = (
    "gcc-avr",
    "avr-libc",
    "arduino-core-avr",
    "simavr",
    "libsimavr-dev",
    "libsimavrparts1",
)
INSTALL_HINT = "run `make avr-deps` (as root: apt-get install -y " + " ".join(APT_PACKAGES) + ")"
FLASH_BYTES = 32 * 1024  # ATmega328P
BOOTLOADER_BYTES = 512  # optiboot on an Uno: what is left for the sketch is 32,256 bytes
RAM_BYTES = 2 * 1024
BUDGET = 0.75  # at most 75 % of flash and of RAM (static + measured stack)


def missing_toolchain() -> str | None:
    """None when the AVR build and simavr harness can be made here, else a one-line reason that
    says how to install what is missing."""
    missing = [tool for tool in ("avr-gcc", "avr-g++", "avr-size", "cc") if not shutil.which(tool)]
    if not (ARDUINO_AVR / "cores" / "arduino" / "Arduino.h").exists():
        missing.append("the Arduino AVR core (arduino-core-avr)")
    if not SIMAVR_INCLUDE.exists():
        missing.append("simavr headers (libsimavr-dev)")
    if not missing:
        return None
    return f"AVR toolchain missing ({', '.join(missing)}): {INSTALL_HINT}"


@contextlib.contextmanager
def _build_lock(build: Path) -> Iterator[None]:
    build.mkdir(parents=True, exist_ok=True)
    with open(build / ".lock", "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _make(targets: Sequence[str], variables: dict[str, str]) -> None:
    reason = missing_toolchain()
    if reason is not None:
        raise HardwareError(reason)
    cmd = ["make", "-s", "-C", str(ARM3_DIR), *targets, *(f"{k}={v}" for k, v in variables.items())]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-15:]
        raise HardwareError(f"`{' '.join(cmd)}` failed:\n" + "\n".join(tail))


@dataclass(frozen=True)
class AvrBuild:
    elf: Path
    harness: Path
    limits_crc: int


def build(spec: ArmSpec | None = None, build_dir: Path = BUILD_DIR) -> AvrBuild:
    """The sketch's ``.elf`` for ``spec`` and the simavr harness; make rebuilds only what changed.
    A spec whose limits are the committed limits.h's (same CRC: the CRC covers every limit) uses
    it; another spec gets a header generated for it, in a build folder of its own."""
    committed_crc = _committed_crc()
    limits = firmware_limits(spec) if spec is not None else None
    variables = {"BUILD": str(build_dir)}
    if limits is None or limits.crc == committed_crc:
        elf_dir = build_dir / "avr"
        crc = committed_crc
    else:
        assert spec is not None
        crc = limits.crc
        elf_dir = build_dir / f"avr-{crc:04x}"
        header = render_limits_header(limits, f"spec {spec.name}, nominal calibration")
        limits_path = elf_dir / "limits.h"
        variables["LIMITS"] = str(limits_path)
    variables["AVR_BUILD"] = str(elf_dir)
    with _build_lock(build_dir):
        if "LIMITS" in variables:
            elf_dir.mkdir(parents=True, exist_ok=True)
            if not limits_path.exists() or limits_path.read_text() != header:
                limits_path.write_text(header)
        _make([str(elf_dir / "arm3.hex"), "sim"], variables)
    return AvrBuild(elf_dir / "arm3.elf", build_dir / "arm3_sim", crc)


def _committed_crc() -> int:
    for line in HEADER_PATH.read_text().splitlines():
        if line.startswith("#define ARM3_LIMITS_CRC"):
            return int(line.split()[-1], 0)
    raise HardwareError(f"{HEADER_PATH.name} has no ARM3_LIMITS_CRC")


@dataclass(frozen=True)
class SizeReport:
    """Flash and RAM use of the ``.elf``; the stack comes from a run (simavr's lowest SP)."""

    flash_bytes: int  # .text + .data (the initialised data is stored in flash too)
    flash_total_bytes: int
    ram_static_bytes: int  # .data + .bss + .noinit
    ram_total_bytes: int
    stack_peak_bytes: int | None = None

    @property
    def flash_fraction(self) -> float:
        return self.flash_bytes / self.flash_total_bytes

    @property
    def ram_fraction(self) -> float:
        return (self.ram_static_bytes + (self.stack_peak_bytes or 0)) / self.ram_total_bytes

    def within_budget(self) -> bool:
        return self.flash_fraction <= BUDGET and self.ram_fraction <= BUDGET

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = asdict(self)
        out["flash_pct"] = round(100 * self.flash_fraction, 1)
        out["ram_pct"] = round(100 * self.ram_fraction, 1)
        out["budget_pct"] = round(100 * BUDGET)
        return out


def size_report(elf: Path, stack_peak_bytes: int | None = None) -> SizeReport:
    """Parse ``avr-size -A`` (section sizes in bytes)."""
    proc = subprocess.run(["avr-size", "-A", str(elf)], capture_output=True, text=True, check=True)
    sections: dict[str, int] = {}
    for line in proc.stdout.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0].startswith(".") and parts[1].isdigit():
            sections[parts[0]] = int(parts[1])
    text, data = sections.get(".text", 0), sections.get(".data", 0)
    bss, noinit = sections.get(".bss", 0), sections.get(".noinit", 0)
    return SizeReport(
        flash_bytes=text + data,
        flash_total_bytes=FLASH_BYTES - BOOTLOADER_BYTES,
        ram_static_bytes=data + bss + noinit,
        ram_total_bytes=RAM_BYTES,
        stack_peak_bytes=stack_peak_bytes,
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Build, print the size report as one JSON line, exit 1 when over budget."""
    del argv
    try:
        result = build()
    except HardwareError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    report = size_report(result.elf)
    print(json.dumps({"bench": "avr_size", "elf": result.elf.name, **report.as_dict()}))
    if not report.within_budget():
        print(f"error: over the {round(100 * BUDGET)} % budget", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
