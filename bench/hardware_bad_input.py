"""Bad input to the hardware CLI: every case must fail with exit code 2, exactly one stderr line
that names the problem, and nothing half-written.

Cases: a wrong port, a busy port, a corrupt calibration YAML, a spec whose limits exceed the servo
range (gen-limits), and a calibration whose mapping puts a limit outside the servo range.

Prints one JSON line per case ("value" is the error line) and exits non-zero if any case fails.

Usage: python bench/hardware_bad_input.py
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import serial

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from support.load import emit_row  # noqa: E402

from hardware.emulator import Emulator  # noqa: E402
from hardware.joint_calibration import nominal_calibration, with_joints  # noqa: E402
from hardware.protocols.s2r import S2RProtocol  # noqa: E402
from hardware.spec import DEFAULT_SPEC_PATH, load_spec  # noqa: E402


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run(
        [sys.executable, "-m", "sim2real", "arm", *args],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        cwd=ROOT,
    )


def check(
    name: str, proc: subprocess.CompletedProcess[str], expect: str, untouched: Callable[[], bool]
) -> bool:
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    one_line = len(lines) == 1 and lines[0].startswith("sim2real arm: error: ")
    ok = proc.returncode == 2 and one_line and expect in proc.stderr and untouched()
    emit_row(
        {
            "metric": f"bad_input_{name}",
            "value": lines[0] if lines else "",
            "unit": "error line",
            "exit_code": proc.returncode,
            "stderr_lines": len(lines),
            "nothing_written": untouched(),
            "target": "exit 2, one line naming the problem, nothing written",
            "pass": ok,
        }
    )
    return ok


def main() -> int:
    spec = load_spec()
    ok = True
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)

        def empty() -> bool:
            return sorted(p.name for p in tmp.iterdir()) == sorted(keep)

        keep: list[str] = []
        ok &= check(
            "wrong_port",
            cli("ping", "--port", "/dev/ttyUSB9", "--protocol", "s2r"),
            "no such serial port '/dev/ttyUSB9'",
            empty,
        )
        with Emulator(spec, "s2r") as emu, serial.Serial(emu.port, 115200, exclusive=True):
            ok &= check("busy_port", cli("ping", "--port", emu.port), "is busy", empty)

        bad_cal = tmp / "lab1.yaml"
        bad_cal.write_text(
            "arm_id: lab1\nprotocol: s2r\njoints:\n  - name: base_yaw\n\toffset_units: 1500\n"
        )
        keep = ["lab1.yaml"]
        before = bad_cal.read_text()
        with Emulator(spec, "s2r") as emu:
            ok &= check(
                "corrupt_calibration_yaml",
                cli("ping", "--port", emu.port, "--arm-id", "lab1", "--calibration-dir", str(tmp)),
                "corrupt calibration YAML",
                lambda: empty() and bad_cal.read_text() == before,
            )

        wide = tmp / "wide_spec.yaml"
        wide.write_text(
            DEFAULT_SPEC_PATH.read_text().replace("upper_rad: 1.57", "upper_rad: 2.2", 1)
        )
        keep = ["lab1.yaml", "wide_spec.yaml"]
        out = tmp / "limits.h"
        ok &= check(
            "spec_limits_exceed_servo_range",
            cli("gen-limits", "--spec", str(wide), "--out", str(out)),
            "more than the servo range",
            lambda: empty() and not out.exists(),
        )

        shifted = with_joints(
            nominal_calibration(spec, "s2r", S2RProtocol.unit_frame(spec), arm_id="lab2"),
            offsets_units=[1700.0, 1500.0, 1500.0, 1500.0],
        )
        shifted.save(tmp / "lab2.yaml")
        keep = ["lab1.yaml", "wide_spec.yaml", "lab2.yaml"]
        ok &= check(
            "calibrated_limits_exceed_servo_range",
            cli("gen-limits", "--calibration", str(tmp / "lab2.yaml"), "--out", str(out)),
            "outside the servo range",
            lambda: empty() and not out.exists(),
        )
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
