"""The arm3 firmware as the chip runs it: the AVR ``.elf`` in simavr, behind a pty, driving the
emulator's servo dynamics with the pulse widths it really produces.

``AvrEmulator`` presents the interface of ``hardware.emulator.server.Emulator`` that hosts, tests
and the deploy code use: a context manager, ``.port``, ``.spec``, ``true_positions_rad()``,
``torque_enabled()``, ``applied()``, ``sync()``, ``brownout()``. The work is split:

* ``hardware/firmware/arm3/sim/arm3_sim.c`` (C against libsimavr) runs the chip in step with wall
  time, bridges UART0 to its own pty and reports, in simulated microseconds, every pulse each
  servo pin produced and every byte the UART received and sent;
* this module turns pulses into servo targets (through the true mounting) and integrates the
  servo dynamics (``ServoBank``) between events, so the horns move as the measured pulses say;
* for a pot build (actuators with ``feedback: measured``) it sets each potentiometer's wiper
  voltage on its analog input from where the horn is, every 10 ms of chip time, so the firmware
  reads the horn with the chip's own ADC.

The ``applied()`` log is rebuilt from the UART traffic: a SET_TARGETS request and the firmware's
STATE reply (which carries its targets after its own clamps) make one "targets" entry, as the
Python model logs them; a retransmission the firmware answered without applying is not logged.
"""

from __future__ import annotations

import contextlib
import math
import os
import subprocess
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hardware.emulator.coupling import BodyCoupling
from hardware.emulator.dynamics import ServoBank, ServoParams
from hardware.emulator.firmware import AppliedCommand
from hardware.emulator.lifecycle import PtyDevice
from hardware.emulator.server import EmulatorConfig
from hardware.errors import HardwareError
from hardware.firmware import avr
from hardware.firmware.limits import ADC_MAX_COUNTS, NO_POT, UNO_PWM_PINS, firmware_limits
from hardware.joint_calibration import ArmCalibration, nominal_calibration
from hardware.protocols import s2r
from hardware.protocols.s2r import S2RFrame, S2RFramer, S2RProtocol
from hardware.spec import ArmSpec, load_spec

SETTLE_S = 0.05  # a pulse train stops being seen as "on" 25 ms after its last pulse, at worst 45
VREF_MV = 5000  # the harness's ADC reference (an Uno's 5 V)


def counts_to_mv(counts: int) -> int:
    """The wiper voltage (mV) the chip's ADC reads as ``counts`` (simavr: mv * 1023 // 5000)."""
    return math.ceil(counts * VREF_MV / ADC_MAX_COUNTS)


def mv_to_counts(mv: int) -> int:
    return mv * ADC_MAX_COUNTS // VREF_MV


class AvrEmulator(BodyCoupling, PtyDevice):
    """The AVR firmware in simavr on a pty. Use as a context manager, or ``start()``/``stop()``.

    Only protocol ``s2r`` (it is our firmware), and of ``EmulatorConfig`` only what belongs to the
    servos (``droop_rad``, ``noise_rad``, ``command_latency_s``, ``seed``): wire timing, the baud
    rate and its error are the simulated UART's own, and fault injection is the Python
    emulator's job."""

    protocol = "s2r"
    baud = 115_200  # what the sketch asks for; the chip really runs at ``baud_actual``

    def __init__(
        self,
        spec: ArmSpec | None = None,
        protocol: str = "s2r",
        config: EmulatorConfig | None = None,
        mounting: ArmCalibration | None = None,
        link: str | os.PathLike[str] | None = None,
        build_dir: Path | None = None,
    ) -> None:
        if protocol != "s2r":
            raise HardwareError(
                f"the AVR firmware speaks protocol 's2r', not {protocol!r}; use the python "
                "firmware (Emulator) for feetech and maestro"
            )
        self.spec = spec or load_spec()
        self.config = config or EmulatorConfig()
        f = self.config.faults
        if f.corrupt_rate or f.corrupt_byte_rate or f.drop_rate or f.delay_rate:
            raise HardwareError(
                "fault injection is not available with --firmware avr; use the python firmware"
            )
        frame = S2RProtocol.unit_frame(self.spec)
        self.mounting = mounting or nominal_calibration(self.spec, "s2r", frame, arm_id="emulator")
        self.mounting.check_spec(self.spec)
        self.mounting.check_protocol("s2r", frame)
        self.link = Path(link) if link is not None else None
        self._build_dir = build_dir or avr.BUILD_DIR
        self.servos = ServoBank(
            ServoParams.from_spec(
                self.spec,
                self.config.droop_rad,
                self.config.noise_rad,
                self.config.command_latency_s,
            ),
            self.spec.actuator_park_rad,
            seed=self.config.seed,
        )
        n = self.spec.n_actuators
        park = self.mounting.to_units(self.spec.actuator_park_rad)
        self._pulse_us = np.array(park, dtype=float)
        self._powered = np.zeros(n, dtype=bool)
        self._lock = threading.RLock()
        self._stdin_lock = threading.Lock()
        self.limits = firmware_limits(self.spec)  # what the build compiles in (its pot map)
        self._pots = [i for i in range(n) if self.limits.pot_channel[i] != NO_POT]
        self._pot_mv: dict[int, int] = {}  # actuator -> the wiper voltage set last
        self._pinned: set[int] = set()  # pots a test holds still (``set_pot_counts``)
        # the chip's logs, appended by the event reader under the lock; read them through the
        # snapshot methods below (iterating a deque the reader appends to raises)
        self._adc_log: list[tuple[float, int, int]] = []
        self._log: list[AppliedCommand] = []
        self._rx = S2RFramer(gap_s=0.5)
        self._tx = S2RFramer(gap_s=0.5)
        self._requests: dict[int, tuple[S2RFrame, bool]] = {}
        self._last_rx: tuple[int, int] | None = None
        self._sim_s = 0.0
        self._t0 = 0.0
        self._proc: subprocess.Popen[str] | None = None
        self._reader: threading.Thread | None = None
        self._running = False
        self.device_path = ""
        self.baud_actual: float | None = None
        self.min_sp: int | None = None
        self.pulses_seen = 0
        self._pulse_log: deque[tuple[float, int, int]] = deque(maxlen=100_000)
        self._off_log: list[tuple[float, int]] = []
        self.crashed: str | None = None
        self._traffic: deque[tuple[str, float, bytes]] = deque(maxlen=100_000)

    # ---- lifecycle ------------------------------------------------------------------------
    def start(self) -> str:
        if self._running:
            return self.port
        result = avr.build(self.spec, self._build_dir)
        pins = [str(UNO_PWM_PINS[sid]) for sid in self.spec.actuator_ids]
        boot_id = (self.config.seed * 7919 + 1) & 0xFFFF or 1
        with self._lock:
            initial = self._pot_commands()
        adc = ",".join(f"{self.limits.pot_channel[i]}={mv}" for i, mv in initial)
        self._proc = subprocess.Popen(
            [str(result.harness), str(result.elf), ",".join(pins), str(boot_id)]
            + ([adc] if adc else []),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            bufsize=1,
        )
        self._t0 = time.monotonic()
        assert self._proc.stdout is not None
        first = self._proc.stdout.readline().split()
        if len(first) != 2 or first[0] != "PTY":
            self._kill()
            raise HardwareError(f"the simavr harness did not start (said {' '.join(first)!r})")
        self.device_path = first[1]
        if self.link is not None:
            with contextlib.suppress(FileNotFoundError):
                if self.link.is_symlink():
                    self.link.unlink()
            if self.link.exists():
                self._kill()
                raise HardwareError(f"--link {str(self.link)!r} exists and is not a symlink")
            self.link.symlink_to(self.device_path)
        self._running = True
        self._reader = threading.Thread(target=self._read_events, name="avr-events", daemon=True)
        self._reader.start()
        # the UART drops bytes until the sketch's Serial.begin(): return once the chip booted
        if not self.wait_until(lambda: self.baud_actual is not None, timeout_s=10.0):
            self.stop()
            raise HardwareError(
                f"the AVR firmware did not start its UART ({self.crashed or 'no reason'})"
            )
        return self.port

    def stop(self) -> None:
        self._running = False
        proc = self._proc
        if proc is not None and proc.poll() is None and proc.stdin is not None:
            with self._stdin_lock, contextlib.suppress(OSError, ValueError):
                proc.stdin.write("Q\n")
                proc.stdin.close()
        self._end_process()
        if self._reader is not None:  # at the harness's EOF: its pipe is closed after, not under it
            self._reader.join(timeout=5.0)
            self._reader = None
        self._close_stdout()
        if self.link is not None and self.link.is_symlink():
            with contextlib.suppress(FileNotFoundError):
                self.link.unlink()

    def _kill(self) -> None:
        self._end_process()
        self._close_stdout()

    def _end_process(self) -> None:
        proc = self._proc
        if proc is None:
            return
        try:
            proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5.0)

    def _close_stdout(self) -> None:
        if self._proc is not None and self._proc.stdout is not None:
            with contextlib.suppress(OSError):
                self._proc.stdout.close()

    def now_s(self) -> float:
        """Simulated time of the chip (seconds since power-up), as far as reported."""
        with self._lock:
            return self._sim_s

    # ---- events from the harness ------------------------------------------------------------
    def _read_events(self) -> None:
        assert self._proc is not None and self._proc.stdout is not None
        # ValueError: stop() gave up waiting for this thread and closed the pipe under it
        with contextlib.suppress(ValueError, OSError):
            for line in self._proc.stdout:
                parts = line.split()
                if not parts:
                    continue
                with self._lock:
                    self._on_event(parts)
        self._running = False

    def _advance(self, t_s: float) -> None:
        """Servo dynamics up to simulated time ``t_s`` with the pulses seen so far (lock held)."""
        if t_s > self._sim_s:
            target = self.mounting.from_units(self._pulse_us)
            self.servos.advance(self._sim_s, t_s, target, self._powered)
            self._sim_s = t_s

    def _on_event(self, parts: list[str]) -> None:
        kind = parts[0]
        if kind == "P":  # a pulse ended
            t_s, ch, width_ns = int(parts[1]) * 1e-6, int(parts[2]), int(parts[3])
            self._advance(t_s)
            width_us = round(width_ns / 1000)
            self._pulse_us[ch] = width_us
            self._powered[ch] = True
            self.pulses_seen += 1
            self._pulse_log.append((t_s, ch, width_ns))
        elif kind == "O":  # a pulse train stopped: the servo goes limp
            t_s, ch = int(parts[1]) * 1e-6, int(parts[2])
            self._advance(t_s)
            self._powered[ch] = False
            self._off_log.append((t_s, ch))
        elif kind == "T":
            self._advance(int(parts[1]) * 1e-6)
            self.min_sp = int(parts[2])
            self._send_pots(self._pot_commands())
        elif kind == "ADC" and len(parts) == 4:
            ch, mv = int(parts[2]), int(parts[3])
            for i in self._pots:
                if self.limits.pot_channel[i] == ch:
                    self._adc_log.append((int(parts[1]) * 1e-6, i, mv_to_counts(mv)))
        elif kind == "RX" and len(parts) == 3:
            t_s = int(parts[1]) * 1e-6
            self._advance(t_s)
            data = bytes.fromhex(parts[2])
            self._traffic.append(("RX", t_s, data))
            for f in self._rx.feed(data, t_s):
                dup = self._last_rx == (f.seq, f.crc)
                self._last_rx = (f.seq, f.crc)
                self._requests[f.seq] = (f, dup)
        elif kind == "TX" and len(parts) == 3:
            t_s = int(parts[1]) * 1e-6
            self._advance(t_s)
            data = bytes.fromhex(parts[2])
            self._traffic.append(("TX", t_s, data))
            for f in self._tx.feed(data, t_s):
                self._on_reply(f, t_s)
        elif kind == "BAUD":
            self.baud_actual = float(parts[1])
        elif kind == "RESET":
            t_s = int(parts[1]) * 1e-6
            self._advance(t_s)
            self._powered[:] = False
            self.servos.drop_pending()
            self._requests.clear()
            self._last_rx = None
            self._log.append(AppliedCommand(t_s, "reset", self.spec.actuator_ids, (), ()))
        elif kind == "CRASH":
            self.crashed = " ".join(parts[1:])

    def _pot_commands(self) -> list[tuple[int, int]]:
        """(actuator, mV) for each wiper that moved since it was last set (lock held)."""
        if not self._pots:
            return []
        us = self.mounting.to_units_float(self.servos.reading_rad())
        out = []
        for i in self._pots:
            if i in self._pinned:
                continue
            mv = counts_to_mv(self.limits.pot_counts(i, float(us[i])))
            if self._pot_mv.get(i) != mv:
                self._pot_mv[i] = mv
                out.append((i, mv))
        return out

    def _send_pots(self, commands: list[tuple[int, int]]) -> None:
        lines = "".join(f"A {self.limits.pot_channel[i]} {mv}\n" for i, mv in commands)
        proc = self._proc
        if lines and proc is not None and proc.stdin is not None:
            with self._stdin_lock, contextlib.suppress(OSError, ValueError):
                proc.stdin.write(lines)
                proc.stdin.flush()

    def set_pot_counts(self, name: str, counts: int | None) -> None:
        """Hold actuator ``name``'s wiper at the voltage the ADC reads as ``counts`` (a test's
        fixed input), or give it back to the horn (None)."""
        i = self.spec.actuator_names.index(name)
        if i not in self._pots:
            raise HardwareError(f"{name} has no potentiometer in this build (feedback: commanded)")
        with self._lock:
            if counts is None:
                self._pinned.discard(i)
                self._pot_mv.pop(i, None)
                return
            self._pinned.add(i)
            self._pot_mv[i] = counts_to_mv(int(counts))
        self._send_pots([(i, counts_to_mv(int(counts)))])

    def _on_reply(self, reply: S2RFrame, t_s: float) -> None:
        found = self._requests.get(reply.seq)
        if found is None:
            return
        request, dup = found
        if dup or reply.type != request.type | s2r.REPLY:
            return
        ids = self.spec.actuator_ids
        if request.type == s2r.SET_TARGETS:
            state = s2r.StatePayload.decode(reply.payload, self.spec.n_actuators)
            requested = s2r.decode_targets(request.payload)
            self._log.append(
                AppliedCommand(t_s, "targets", ids, tuple(requested), state.targets, reply.seq)
            )
        elif request.type == s2r.TORQUE:
            v = 1 if request.payload[0] == 1 else 0
            self._log.append(AppliedCommand(t_s, "torque", (v,), (v,), (v,), reply.seq))

    # ---- observation (thread-safe) ----------------------------------------------------------
    def applied(self, kind: str | None = None) -> list[AppliedCommand]:
        with self._lock:
            return [e for e in self._log if kind is None or e.kind == kind]

    def clear_log(self) -> None:
        with self._lock:
            self._log.clear()

    def torque_enabled(self) -> np.ndarray:
        """Which servos get pulses right now (n_actuators,) bool."""
        with self._lock:
            return self._powered.copy()

    def device_targets_rad(self) -> np.ndarray:
        """What the chip drives the servos towards right now (its latest pulses), in rad."""
        with self._lock:
            return self.mounting.from_units(self._pulse_us)

    def pulses(self) -> list[tuple[float, int, int]]:
        """Every measured pulse so far (the newest 100,000): (simulated s, channel, width ns)."""
        with self._lock:
            return list(self._pulse_log)

    def pulse_stops(self) -> list[tuple[float, int]]:
        """Every pulse train that stopped (the servo went limp): (simulated s, channel)."""
        with self._lock:
            return list(self._off_log)

    def adc_readings(self) -> list[tuple[float, int, int]]:
        """Every wiper change as the chip's ADC saw it: (simulated s, actuator, ADC counts)."""
        with self._lock:
            return list(self._adc_log)

    def uart_traffic(self) -> list[tuple[str, float, bytes]]:
        """The UART's traffic as the chip saw it (the newest 100,000 chunks): ("RX" | "TX",
        simulated s, bytes)."""
        with self._lock:
            return list(self._traffic)

    def pulse_widths_us(self) -> np.ndarray:
        """The latest measured pulse width per servo, rounded to whole µs."""
        with self._lock:
            return self._pulse_us.copy()

    def stack_peak_bytes(self) -> int | None:
        """Deepest stack seen so far: RAMEND (0x8FF) minus the lowest stack pointer."""
        with self._lock:
            return None if self.min_sp is None else 0x8FF - self.min_sp

    def sync(self, timeout_s: float = 2.0) -> bool:
        """Wait until the chip has run ``SETTLE_S`` past now: bytes written before the call are
        processed and a pulse train that stopped is seen as stopped."""
        goal = (time.monotonic() - self._t0) + SETTLE_S
        return self.wait_until(lambda: self.now_s() >= goal, timeout_s)

    def brownout(self) -> None:
        """Supply dip: the chip resets (EEPROM kept: a new boot id), servos limp."""
        proc = self._proc
        if proc is None or proc.stdin is None:
            raise HardwareError("the AVR emulator is not running")
        with self._stdin_lock:
            proc.stdin.write("B\n")
            proc.stdin.flush()
        with self._lock:
            self._pot_mv.clear()  # the harness keeps its inputs; the next beat refreshes them

    def stats(self) -> dict[str, float]:
        with self._lock:
            return {
                "pulses": self.pulses_seen,
                "baud_actual": self.baud_actual or 0.0,
                "stack_peak_bytes": self.stack_peak_bytes() or 0,
            }

    def wait_until(
        self, predicate: Callable[[], bool], timeout_s: float = 2.0, poll_s: float = 0.002
    ) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if predicate():
                return True
            if not self._running:
                break
            time.sleep(poll_s)
        return predicate()
