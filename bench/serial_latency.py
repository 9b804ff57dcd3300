"""Round-trip latency of one control step, command() + read_state(), through SerialArm and the
emulator over a real pty, at 115200 baud and 1 Mbps, for each protocol.

The emulator charges the wire time a real UART would take (10 bits per byte), so the figures
include it; "wire_ms" is that floor for the bytes one step moves, measured from the link's byte
counters in the same run, and "overhead_ratio" is p50 / wire_ms.

Prints one JSON line per (protocol, baud). Target: p99 well inside a 20 Hz control period (50 ms).

Usage: python bench/serial_latency.py [--steps 1000]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from support.load import emit_row

from hardware.emulator import Emulator, EmulatorConfig
from hardware.serial_arm import SerialArm
from hardware.spec import load_spec

PERIOD_MS = 50.0  # the deploy loop's 20 Hz


def measure(protocol: str, baud: int, steps: int) -> bool:
    spec = load_spec()
    config = EmulatorConfig(baud=baud, maestro_serial_timeout_s=0.0)
    with (
        Emulator(spec, protocol, config) as emu,
        SerialArm(spec, emu.port, protocol=protocol, baud=baud, host_watchdog_s=None) as arm,
    ):
        arm.enable()
        assert arm.link is not None
        goal = spec.actuator_home_rad.copy()
        for _ in range(20):  # warm-up
            arm.command(goal)
            arm.read_state()
        b_in, b_out = arm.link.bytes_in, arm.link.bytes_out
        times = np.empty(steps)
        for k in range(steps):
            goal[0] = 0.3 * np.sin(k / 25.0)
            t = time.perf_counter()
            arm.command(goal)
            arm.read_state()
            times[k] = time.perf_counter() - t
        wire_bytes = (arm.link.bytes_in - b_in + arm.link.bytes_out - b_out) / steps
    wire_ms = wire_bytes * 10.0 / baud * 1000.0
    p50, p99 = (float(np.percentile(times, q)) * 1000.0 for q in (50, 99))
    ok = p99 < PERIOD_MS
    emit_row(
        {
            "metric": f"roundtrip_{protocol}_{baud}",
            "value": round(p50, 3),
            "unit": "ms (p50, command+read_state)",
            "p99_ms": round(p99, 3),
            "max_ms": round(float(times.max()) * 1000.0, 3),
            "wire_ms": round(wire_ms, 3),
            "bytes_per_step": round(wire_bytes, 1),
            "overhead_ratio": round(p50 / wire_ms, 2),
            "steps": steps,
            "target": f"p99 < {PERIOD_MS:.0f} ms (one 20 Hz period)",
            "pass": ok,
        }
    )
    return ok


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000)
    args = parser.parse_args()
    ok = True
    for protocol in ("s2r", "feetech", "maestro"):
        for baud in (115200, 1_000_000):
            ok &= measure(protocol, baud, args.steps)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
