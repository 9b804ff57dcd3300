"""The arm3 firmware as the chip runs it, next to the Python firmware model.

Prints JSON lines:
  * avr_size: flash and RAM of the .elf (RAM with the deepest stack simavr saw in this run);
  * roundtrip_s2r_{python,avr}: one control step, command() + read_state(), through SerialArm
    over a pty, p50 / p99 in ms, and the AVR's ratio to the Python emulator measured in the same
    run (the simulated UART runs at the Uno's real 117,647 baud, 16 MHz time);
  * pulse_width: measured pulse widths against whole microseconds (edge timing of Timer1);
  * idle_cpu_{python,avr}: CPU used by an idle emulator (torque off, nothing sent) as a fraction
    of one core, and (python) how many times its serving thread woke up.

Needs the Debian AVR packages for the AVR lines (`make avr-deps`); without them it prints the
Python lines and a skip line. Target: AVR round-trip p99 inside a 20 Hz period (50 ms), sketch
within 75 % of flash and RAM.

Usage: python bench/avr_firmware.py [--steps 500]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from support.load import emit_row

from hardware.emulator import AvrEmulator, Emulator
from hardware.firmware import avr
from hardware.serial_arm import SerialArm
from hardware.spec import ArmSpec, load_spec

PERIOD_MS = 50.0
IDLE_S = 3.0


def roundtrip(emu: Emulator | AvrEmulator, spec: ArmSpec, steps: int) -> np.ndarray:
    with SerialArm(spec, emu.port, protocol="s2r", host_watchdog_s=None) as arm:
        arm.enable()
        goal = spec.actuator_home_rad.copy()
        for _ in range(20):
            arm.command(goal)
            arm.read_state()
        times = np.empty(steps)
        for k in range(steps):
            goal[0] = 0.3 * np.sin(k / 25.0)
            t = time.perf_counter()
            arm.command(goal)
            arm.read_state()
            times[k] = time.perf_counter() - t
    return times * 1000.0


def proc_cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=500)
    args = parser.parse_args()
    spec = load_spec()
    ok = True

    with Emulator(spec, "s2r") as emu:
        py_ms = roundtrip(emu, spec, args.steps)
        emu.sync()
        wakes0, cpu0, t0 = emu._iterations, time.process_time(), time.perf_counter()
        time.sleep(IDLE_S)
        cpu = (time.process_time() - cpu0) / (time.perf_counter() - t0)
        wakes = emu._iterations - wakes0
    emit_row(
        {
            "metric": "idle_cpu_python",
            "core_fraction": round(cpu, 4),
            "wakeups_per_s": round(wakes / IDLE_S, 2),
        }
    )
    p50, p99 = (float(np.percentile(py_ms, q)) for q in (50, 99))
    emit_row({"metric": "roundtrip_s2r_python", "p50_ms": round(p50, 3), "p99_ms": round(p99, 3)})

    reason = avr.missing_toolchain()
    if reason is not None:
        emit_row({"metric": "avr", "skipped": reason})
        return 0 if ok else 1
    build = avr.build()
    with AvrEmulator(spec) as chip:
        assert chip._proc is not None
        pid = chip._proc.pid
        chip.sync()
        c0, t0 = proc_cpu_s(pid), time.perf_counter()
        time.sleep(IDLE_S)
        idle = (proc_cpu_s(pid) - c0) / (time.perf_counter() - t0)
        avr_ms = roundtrip(chip, spec, args.steps)
        c0, t0 = proc_cpu_s(pid), time.perf_counter()
        with SerialArm(spec, chip.port, protocol="s2r", host_watchdog_s=None) as arm:
            arm.enable()
            outputs = arm.calibration.to_units(arm.read_state().positions_rad)
            t_steady = chip.now_s() + 0.05
            time.sleep(IDLE_S)  # torque on: four pulse trains, nothing sent
            pulsing = (proc_cpu_s(pid) - c0) / (time.perf_counter() - t0)
            chip.sync()
        errors_ns = np.array(
            [abs(w - 1000 * int(outputs[ch])) for t, ch, w in chip.pulses() if t > t_steady]
        )
        stack = chip.stack_peak_bytes()
        baud = chip.baud_actual
    report = avr.size_report(build.elf, stack_peak_bytes=stack)
    ok &= report.within_budget()
    emit_row({"metric": "avr_size", **report.as_dict(), "ok": report.within_budget()})
    a50, a99 = (float(np.percentile(avr_ms, q)) for q in (50, 99))
    ok &= a99 < PERIOD_MS
    emit_row(
        {
            "metric": "roundtrip_s2r_avr",
            "p50_ms": round(a50, 3),
            "p99_ms": round(a99, 3),
            "p50_ratio_to_python": round(a50 / p50, 2),
            "uart_baud": baud,
            "ok": a99 < PERIOD_MS,
        }
    )
    emit_row(
        {
            "metric": "pulse_width_vs_output",
            "pulses": int(errors_ns.size),
            "abs_error_p50_ns": float(np.percentile(errors_ns, 50)),
            "abs_error_p99_ns": float(np.percentile(errors_ns, 99)),
            "abs_error_max_ns": float(errors_ns.max()),
            "share_within_0.5us": round(float(np.mean(errors_ns < 500)), 4),
        }
    )
    emit_row(
        {
            "metric": "idle_cpu_avr",
            "core_fraction_torque_off": round(idle, 4),
            "core_fraction_pulsing": round(pulsing, 4),
        }
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
