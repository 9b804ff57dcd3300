"""Serial fault tolerance: 100,000 commands through SerialArm to the emulated firmware (protocol s2r)
over a real pty with faults injected, then the firmware watchdog after a cut link.

Prints JSON lines (one per figure, each with "metric", "value", "unit", "target", "pass"):
  * corrupted_commands_applied: every command the emulator applied is compared with what the
    host sent (same order, same values); target 0;
  * lost_or_duplicated_commands: each host command applied exactly once; target 0;
  * faults_detected: injected faults (frames corrupted or dropped, both directions) against
    failed attempts the host noticed (each one a timeout or bad CRC, then a retry); target 1.0;
  * the same with per-byte corruption (every byte corrupted with probability 1 %);
  * watchdog_stop_ms: time from the last valid frame to the firmware holding position after the
    link is cut, worst of several cuts; target: the 250 ms watchdog (+1 ms firmware tick).

Fault model of the main run: 1 % of frames get one corrupted byte and 1 % of frames are dropped,
independently in each direction (host -> device and device -> host).

Usage: python bench/serial_faults.py [--commands 100000] [--byte-commands 5000] [--cuts 10]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from support.load import emit_row

from hardware.emulator import Emulator, EmulatorConfig, FaultConfig
from hardware.errors import HardwareError
from hardware.serial_arm import SerialArm
from hardware.spec import load_spec

BAUD = 1_000_000
TIMEOUT_S = 0.02


def emit(
    metric: str, value: Any, unit: str, target: Any = None, ok: bool | None = None, **extra: Any
) -> None:
    row: dict[str, Any] = {"metric": metric, "value": value, "unit": unit}
    if target is not None:
        row["target"] = target
    if ok is not None:
        row["pass"] = bool(ok)
    row.update(extra)
    emit_row(row)


def fault_run(n: int, faults: FaultConfig, retries: int, label: str) -> bool:
    spec = load_spec()
    lo, hi = spec.actuator_lower_rad, spec.actuator_upper_rad
    config = EmulatorConfig(baud=BAUD, reply_latency_s=0.0)
    rng = np.random.default_rng(0)
    with (
        Emulator(spec, "s2r", config) as emu,
        SerialArm(
            spec, emu.port, baud=BAUD, timeout_s=TIMEOUT_S, retries=retries, host_watchdog_s=None
        ) as arm,
    ):
        arm.enable()
        emu.clear_log()
        host0 = arm.stats()
        emu.set_faults(faults)
        sent = np.zeros((n, spec.n_actuators), dtype=np.int64)
        gave_up = 0
        goal = spec.actuator_home_rad.copy()
        t0 = time.perf_counter()
        for k in range(n):
            if k % 40 == 0:
                goal = rng.uniform(lo, hi)
            try:
                arm.command(goal)
            except HardwareError:
                gave_up += 1
            sent[k] = arm.last_sent_units
        elapsed = time.perf_counter() - t0
        emu.set_faults(FaultConfig())
        emu.sync()
        host = {k: v - host0.get(k, 0) for k, v in arm.stats().items()}
        st = emu.stats()
        applied = np.array([e.requested for e in emu.applied("targets")], dtype=np.int64)
    if len(applied) == n:
        corrupted = int(np.sum(np.any(applied != sent, axis=1)))
        lost = 0
    else:
        lost = abs(len(applied) - n)
        m = min(len(applied), n)
        corrupted = int(np.sum(np.any(applied[:m] != sent[:m], axis=1)))
    injected = st["rx_corrupted"] + st["rx_dropped"] + st["tx_corrupted"] + st["tx_dropped"]
    detected = host["timeouts"]
    ratio = detected / injected if injected else 1.0
    emit(
        f"{label}_commands",
        n,
        "commands",
        throughput_per_s=round(n / elapsed, 1),
        seconds=round(elapsed, 1),
    )
    emit(f"{label}_corrupted_commands_applied", corrupted, "commands", 0, corrupted == 0)
    emit(f"{label}_lost_or_duplicated_commands", lost + gave_up, "commands", 0, lost + gave_up == 0)
    ok = injected > 0 and detected >= injected
    emit(
        f"{label}_faults_detected",
        round(min(ratio, 1.0), 6),
        "fraction",
        1.0,
        ok,
        injected=injected,
        detected_failed_attempts=detected,
        spurious_timeouts=max(0, detected - injected),
        rx_corrupted=st["rx_corrupted"],
        rx_dropped=st["rx_dropped"],
        tx_corrupted=st["tx_corrupted"],
        tx_dropped=st["tx_dropped"],
        device_crc_errors=st["device_crc_errors"],
        device_header_errors=st["device_header_errors"],
        device_duplicates_not_reapplied=st["device_duplicates"],
        host_crc_errors=host["rx_crc_errors"],
        host_retries=host["retries"],
    )
    return corrupted == 0 and lost + gave_up == 0 and ok


def watchdog_run(cuts: int) -> bool:
    spec = load_spec()
    stops, frozen = [], True
    with (
        Emulator(spec, "s2r", EmulatorConfig(baud=BAUD)) as emu,
        SerialArm(spec, emu.port, baud=BAUD, host_watchdog_s=None) as arm,
    ):
        for trial in range(cuts):
            arm.enable()
            goal = spec.actuator_home_rad.copy()
            for k in range(25):  # keep the arm moving up to the cut
                goal[0] = 0.4 * np.sin(0.2 * k + trial)
                arm.command(goal)
            emu.cut()
            before = len(emu.applied("watchdog_hold"))

            def tripped(b: int = before) -> bool:
                return len(emu.applied("watchdog_hold")) > b

            if not emu.wait_until(tripped, 2.0):
                emit("watchdog_stop_ms", None, "ms", 250, False, error="the watchdog never fired")
                return False
            hold = emu.applied("watchdog_hold")[-1]
            last = [
                e for e in emu.applied() if e.kind in ("targets", "torque") and e.t_s <= hold.t_s
            ][-1]
            stops.append((hold.t_s - last.t_s) * 1000)
            a = emu.device_targets_rad()
            time.sleep(0.1)
            frozen &= bool(np.array_equal(a, emu.device_targets_rad()))  # held: no more motion
            emu.wait_until(lambda: not emu.torque_enabled().any(), 2.0)
            emu.restore()
    worst = max(stops)
    limit = spec.safety.watchdog_timeout_s * 1000 + 1.0
    emit(
        "watchdog_stop_ms",
        round(worst, 1),
        "ms",
        f"<= {limit:.0f} (250 ms watchdog + 1 ms firmware tick)",
        worst <= limit and frozen,
        p50_ms=round(float(np.median(stops)), 1),
        cuts=cuts,
        outputs_frozen_after_hold=frozen,
        detached_after_ms=round(
            spec.safety.watchdog_timeout_s * 1000 + spec.safety.hold_before_disable_s * 1000
        ),
    )
    return worst <= limit and frozen


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--commands", type=int, default=100_000)
    parser.add_argument("--byte-commands", type=int, default=5_000)
    parser.add_argument("--cuts", type=int, default=10)
    args = parser.parse_args()
    ok = fault_run(
        args.commands, FaultConfig(corrupt_rate=0.01, drop_rate=0.01, seed=1), 8, "frame_faults"
    )
    if args.byte_commands:
        ok &= fault_run(
            args.byte_commands,
            FaultConfig(corrupt_byte_rate=0.01, drop_rate=0.01, seed=2),
            14,
            "byte_faults",
        )
    ok &= watchdog_run(args.cuts)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
