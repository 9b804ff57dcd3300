"""``sim2real arm``: talk to the servo arm (or its emulator) from a shell.

    sim2real arm emulate --protocol s2r --link /tmp/arm3        # mock hardware on a pty
    sim2real arm emulate --plant hard --link /tmp/arm3          # ... of an arm that is off spec
    sim2real arm emulate --firmware avr --link /tmp/arm3        # ... the AVR .elf in simavr
    sim2real arm ping --port /tmp/arm3 --protocol s2r
    sim2real arm home --port /tmp/arm3 --protocol s2r
    sim2real arm jog --port /tmp/arm3 --protocol s2r            # "elbow +0.1", "home", "q"
    sim2real arm calibrate --port /tmp/arm3 --protocol s2r --arm-id lab1
    sim2real arm find-port
    sim2real arm gen-limits --out hardware/firmware/arm3/src/limits.h

Imports only the hardware layer (numpy + pyserial) and the arm connection's options
(``sim2real.deploy.connection``, numpy alone), so it runs on a Raspberry Pi beside the arm.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import FrameType

import numpy as np

from hardware.atomic import atomic_write_text
from hardware.errors import CalibrationFileError, HardwareError, SafetyError
from hardware.joint_calibration import (
    ArmCalibration,
    JointCalibration,
    calibration_path,
    fit_joint,
    nominal_calibration,
    with_joints,
)
from hardware.protocols import PROTOCOLS, get_protocol
from hardware.serial_arm import SerialArm
from hardware.spec import ArmSpec, load_spec
from sim2real.deploy.connection import add_arm_options, arm_connection

KEEPALIVE_S = 0.1  # while waiting for the user, resend the targets this often (watchdogs)


# ---- input ------------------------------------------------------------------------------------
class LineReader:
    """Line input with a timeout, on the raw fd (so select() and buffering agree), so a prompt
    can keep the arm's watchdogs fed while the user thinks."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self._buf = b""
        self.eof = False

    def readline(self, timeout_s: float) -> str | None:
        """A line without its newline, None on timeout; raises EOFError at end of input."""
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self._buf:
            if self.eof:
                if self._buf:
                    line, self._buf = self._buf, b""
                    return line.decode(errors="replace").strip()
                raise EOFError
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            ready, _, _ = select.select([self.fd], [], [], remaining)
            if not ready:
                return None
            chunk = os.read(self.fd, 4096)
            if not chunk:
                self.eof = True
            self._buf += chunk
        line, _, self._buf = self._buf.partition(b"\n")
        return line.decode(errors="replace").strip()


def _prompt(reader: LineReader, text: str, keepalive: Callable[[], object]) -> str:
    print(text, end="", flush=True)
    while True:
        line = reader.readline(KEEPALIVE_S)
        if line is not None:
            return line
        keepalive()


# ---- shared arguments -------------------------------------------------------------------------
def _add_spec(p: argparse.ArgumentParser) -> None:
    p.add_argument("--spec", default=None, help="ArmSpec YAML (default: the shipped arm3 spec)")


def _add_port(p: argparse.ArgumentParser, calibration: bool = True) -> None:
    add_arm_options(p, ("serial",), only=("port", "baud"))  # --port, --protocol, --baud
    p.add_argument("--timeout-ms", type=float, default=50.0, help="reply timeout per try")
    p.add_argument(
        "--maestro-crc",
        action="store_true",
        help="maestro: send a CRC-7 byte with every command (only if you enabled 'Serial CRC' in "
        "the Maestro Control Center; the factory setting is off)",
    )
    if calibration:
        p.add_argument("--calibration", default=None, help="joint calibration YAML")
        p.add_argument("--arm-id", default=None, help="load the calibration saved for this arm id")
        p.add_argument("--calibration-dir", default=None, help="where calibrations live")
    _add_spec(p)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="arm_command", metavar="ARM_COMMAND", required=True)

    p = sub.add_parser("emulate", help="serve an emulated arm on a pseudo-terminal")
    p.add_argument("--protocol", default="s2r", choices=sorted(PROTOCOLS))
    p.add_argument(
        "--firmware",
        default="python",
        choices=["avr", "python"],
        help="python: the firmware model (any protocol, faults); avr: the arm3 .elf in simavr "
        "(s2r; needs `make avr-deps`)",
    )
    p.add_argument(
        "--maestro-crc",
        action="store_true",
        help="maestro: emulate 'Serial CRC' on (factory setting: off)",
    )
    p.add_argument(
        "--maestro-timeout-ms",
        type=float,
        default=0.0,
        help="maestro: its serial timeout, channels off after this long without a command "
        "(factory setting: 0 = off; the hardware guide sets 250)",
    )
    p.add_argument(
        "--link", default=None, help="also create this symlink to the pty (e.g. /tmp/arm3)"
    )
    p.add_argument(
        "--baud", type=int, default=None, help="the device's baud (default: the protocol's)"
    )
    p.add_argument("--latency-ms", type=float, default=0.2, help="device processing latency")
    p.add_argument("--jitter-ms", type=float, default=0.0, help="uniform extra latency")
    p.add_argument("--noise-rad", type=float, default=0.0, help="position reading noise (std)")
    p.add_argument("--droop-rad", type=float, default=0.0, help="gravity sag of the pitch joints")
    p.add_argument(
        "--command-latency-ms",
        type=float,
        default=0.0,
        help="servo dead time: a received target takes effect this much later",
    )
    p.add_argument("--corrupt", type=float, default=0.0, help="probability a frame gets a bad byte")
    p.add_argument("--drop", type=float, default=0.0, help="probability a frame is lost")
    p.add_argument("--delay-rate", type=float, default=0.0, help="probability a reply is late")
    p.add_argument("--delay-ms", type=float, default=200.0, help="how late a late reply is")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--mounting-offset", default=None, help="true servo units at angle 0, comma-separated"
    )
    p.add_argument(
        "--mounting-direction", default=None, help="true directions (1/-1), comma-separated"
    )
    p.add_argument("--duration-s", type=float, default=None, help="stop after this long")
    p.add_argument("--log", default=None, help="write the applied-command log here (JSON lines)")
    p.add_argument(
        "--plant",
        default=None,
        help="emulate this plant (file or preset: mild, moderate, hard): the arm as it is",
    )
    _add_spec(p)

    p = sub.add_parser("ping", help="check the device answers; print what it is and its state")
    _add_port(p)

    p = sub.add_parser("home", help="enable torque and move to the home pose")
    _add_port(p)
    p.add_argument("--then-park", action="store_true", help="park before releasing torque")

    p = sub.add_parser("jog", help="move joints interactively ('elbow +0.1', 'home', 'park', 'q')")
    _add_port(p)

    p = sub.add_parser("calibrate", help="measure offset, direction and scale of every joint")
    _add_port(p, calibration=False)
    p.add_argument("--arm-id", required=True, help="name to save the calibration under")
    p.add_argument("--calibration-dir", default=None, help="where calibrations live")
    p.add_argument("--reference-rad", type=float, default=0.5, help="second pose: +this from zero")

    p = sub.add_parser("find-port", help="list serial ports; --unplug finds the arm's by diffing")
    p.add_argument("--unplug", action="store_true", help="ask to unplug the arm and diff the lists")

    p = sub.add_parser("gen-limits", help="write the firmware's limits.h from the spec")
    _add_spec(p)
    p.add_argument("--calibration", default=None, help="s2r joint calibration YAML")
    p.add_argument("--out", required=True, help="where to write limits.h")


# ---- helpers ----------------------------------------------------------------------------------
def _spec(args: argparse.Namespace) -> ArmSpec:
    return load_spec(args.spec)


def _calibration(args: argparse.Namespace, spec: ArmSpec) -> ArmCalibration | None:
    if getattr(args, "calibration", None):
        return ArmCalibration.load(args.calibration)
    if getattr(args, "arm_id", None):
        return ArmCalibration.load(calibration_path(args.arm_id, args.calibration_dir))
    return None


def _open_arm(
    args: argparse.Namespace,
    spec: ArmSpec,
    calibration: ArmCalibration | None = None,
    push_limits: bool = True,
) -> SerialArm:
    conn = arm_connection(args)
    assert conn.port is not None  # required on the command line
    return SerialArm(
        spec,
        conn.port,
        protocol=conn.protocol,
        baud=conn.baud,
        calibration=calibration if calibration is not None else _calibration(args, spec),
        timeout_s=args.timeout_ms / 1000.0,
        push_limits=push_limits,
        protocol_options={"crc": True} if args.maestro_crc and conn.protocol == "maestro" else None,
    )


def _fmt(spec: ArmSpec, q: np.ndarray) -> str:
    return ", ".join(f"{n}={v:+.3f}" for n, v in zip(spec.actuator_names, q, strict=True))


def _csv(text: str | None, n: int, cast: Callable[[str], float]) -> list[float] | None:
    if text is None:
        return None
    parts = [s for s in text.split(",") if s.strip()]
    if len(parts) != n:
        raise HardwareError(f"expected {n} comma-separated values, got {text!r}")
    try:
        return [cast(s) for s in parts]
    except ValueError:
        raise HardwareError(f"not a list of numbers: {text!r}") from None


# ---- subcommands ------------------------------------------------------------------------------
def _emulate(args: argparse.Namespace) -> int:
    from hardware.emulator import FIRMWARES, AvrEmulator, Emulator, EmulatorConfig, FaultConfig

    spec = _spec(args)
    proto = get_protocol(args.protocol)
    mounting = None
    offsets = _csv(args.mounting_offset, spec.n_actuators, float)
    directions = _csv(args.mounting_direction, spec.n_actuators, int)
    if offsets is not None or directions is not None:
        base = nominal_calibration(spec, args.protocol, proto.unit_frame(spec), arm_id="emulator")
        mounting = with_joints(base, offsets, [int(d) for d in directions] if directions else None)
    config = EmulatorConfig(
        baud=args.baud,
        reply_latency_s=args.latency_ms / 1000.0,
        latency_jitter_s=args.jitter_ms / 1000.0,
        noise_rad=args.noise_rad,
        droop_rad=args.droop_rad,
        command_latency_s=args.command_latency_ms / 1000.0,
        seed=args.seed,
        faults=FaultConfig(
            corrupt_rate=args.corrupt,
            drop_rate=args.drop,
            delay_rate=args.delay_rate,
            delay_s=args.delay_ms / 1000.0,
            seed=args.seed,
        ),
        maestro_crc=args.maestro_crc,
        maestro_serial_timeout_s=args.maestro_timeout_ms / 1000.0,
    )
    if args.firmware != "python" and args.plant is not None:
        raise HardwareError(f"--plant needs --firmware python, not {args.firmware!r}")
    emulator: Emulator | AvrEmulator
    if args.plant is not None:
        from hardware.plant import load_plant

        if mounting is not None or args.droop_rad or args.noise_rad or args.command_latency_ms:
            raise HardwareError(
                "--plant carries droop, noise, command latency and joint offsets: give them in "
                "the plant file, not as --droop-rad/--noise-rad/--command-latency-ms/--mounting-*"
            )
        plant = load_plant(args.plant)
        plant.check_against(spec)
        emulator = plant.emulator(args.protocol, config, link=args.link)
    else:
        emulator = FIRMWARES[args.firmware](
            spec, args.protocol, config, mounting=mounting, link=args.link
        )
    stop = False

    def on_signal(signum: int, frame: FrameType | None) -> None:
        nonlocal stop
        stop = True

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        port = emulator.start()
        print(port, flush=True)
        print(
            f"emulating {args.protocol} ({proto.description}, {args.firmware} firmware) at "
            f"{emulator.baud} baud on "
            f"{emulator.device_path}; Ctrl-C to stop",
            file=sys.stderr,
            flush=True,
        )
        t_end = None if args.duration_s is None else time.monotonic() + args.duration_s
        while not stop and (t_end is None or time.monotonic() < t_end):
            time.sleep(0.05)
    finally:
        emulator.stop()
        for s, h in old.items():
            signal.signal(s, h)
    if args.log:
        lines = [json.dumps(e.__dict__) for e in emulator.applied()]
        atomic_write_text(args.log, "\n".join(lines) + ("\n" if lines else ""))
    return 0


def _ping(args: argparse.Namespace) -> int:
    spec = _spec(args)
    with _open_arm(args, spec) as arm:
        info = arm.info
        state = arm.read_state()
        assert info is not None
        print(f"{args.port}: {info.description}")
        print(f"state: {_fmt(spec, state.positions_rad)} rad")
    return 0


def _home(args: argparse.Namespace) -> int:
    spec = _spec(args)
    with _open_arm(args, spec) as arm:
        state = arm.home()
        print(f"home: {_fmt(spec, state.positions_rad)} rad")
        if args.then_park:
            state = arm.park()
            print(f"parked: {_fmt(spec, state.positions_rad)} rad")
    return 0


def _jog(args: argparse.Namespace) -> int:
    spec = _spec(args)
    reader = LineReader(sys.stdin.fileno())
    names = spec.actuator_names
    with _open_arm(args, spec) as arm:
        arm.enable()
        print(
            f"jog: joints {', '.join(names)}; '<joint> <delta_rad>', 'home', 'park', 'state', 'q'"
        )
        while True:
            try:
                line = _prompt(reader, "jog> ", arm.hold)
            except EOFError:
                break
            words = line.split()
            if not words:
                continue
            if words[0] in ("q", "quit", "exit"):
                break
            if words[0] in ("home", "park"):
                state = arm.home() if words[0] == "home" else arm.park()
            elif words[0] == "state":
                state = arm.read_state()
            elif words[0] in names and len(words) == 2:
                try:
                    delta = float(words[1])
                except ValueError:
                    print(f"not a number: {words[1]!r}")
                    continue
                target = arm.last_sent_rad
                assert target is not None
                target[names.index(words[0])] += delta
                try:
                    state = arm.move_to(target)
                except SafetyError as exc:  # the workspace guard: stay put, keep jogging
                    print(f"  {exc}")
                    continue
            else:
                print(
                    f"unknown command {line!r}; use '<joint> <delta_rad>' with joint one of "
                    f"{', '.join(names)}, or home, park, state, q"
                )
                continue
            print(f"  {_fmt(spec, state.positions_rad)}")
    return 0


_JOG_HELP = (
    "  keys: '+'/'-' one degree, '++'/'--' ten degrees, '+N'/'-N' N servo units, '=U' go to U "
    "units, Enter to accept, 'q' to abort"
)


def _jog_units(arm: SerialArm, reader: LineReader, i: int, deg_units: float) -> int:
    """Jog actuator ``i`` in raw servo units until the user presses Enter; returns the units."""
    while True:
        try:
            line = _prompt(
                reader,
                f"  [{int(arm.last_sent_units[i])} units] > ",
                lambda: arm.command_units(arm.last_sent_units),
            )
        except EOFError:
            raise HardwareError(
                "input ended before the calibration was finished; nothing was written"
            ) from None
        if line == "":
            # where the device really holds the joint (its own limits may have clamped the jog)
            reading = arm.read_units()
            held = reading.targets if reading.targets is not None else arm.last_sent_units
            return int(held[i])
        if line in ("q", "quit"):
            raise HardwareError("calibration aborted by the user; nothing was written")
        goal = arm.last_sent_units.copy()
        try:
            if line in ("+", "-"):
                goal[i] += round(deg_units) * (1 if line == "+" else -1)
            elif line in ("++", "--"):
                goal[i] += round(10 * deg_units) * (1 if line == "++" else -1)
            elif line[0] in "+-":
                goal[i] += int(line)
            elif line[0] == "=":
                goal[i] = int(line[1:])
            else:
                raise ValueError
        except ValueError:
            print(_JOG_HELP)
            continue
        for _ in range(1000):  # walk there through the step clamp, 50 Hz
            sent = arm.command_units(goal)
            if (
                sent[i] == goal[i]
                or sent[i] == arm.calibration.frame.unit_min
                or sent[i] == arm.calibration.frame.unit_max
            ):
                break
            time.sleep(0.02)


def _calibrate(args: argparse.Namespace) -> int:
    spec = _spec(args)
    out = calibration_path(args.arm_id, args.calibration_dir)  # validates the id before moving
    proto = get_protocol(args.protocol)
    nominal = nominal_calibration(spec, args.protocol, proto.unit_frame(spec), arm_id=args.arm_id)
    reader = LineReader(sys.stdin.fileno())
    refs = [args.reference_rad] * spec.n_joints
    if spec.gripper is not None:
        refs.append(spec.gripper.open_rad - spec.gripper.closed_rad)
    deg_units = nominal.frame.units_per_rad * np.pi / 180.0
    joints: list[JointCalibration] = []
    # Raw units, device-side limits at their compiled values: the rad mapping is what we measure.
    with _open_arm(args, spec, calibration=nominal, push_limits=False) as arm:
        arm.enable()
        print(
            f"calibrating {args.arm_id} ({args.protocol}): {spec.n_actuators} actuators, "
            f"units {nominal.frame.units}"
        )
        print(_JOG_HELP)
        for i, name in enumerate(spec.actuator_names):
            zero_what = (
                "closed" if spec.gripper is not None and name == spec.gripper.name else "zero"
            )
            print(
                f"[{i + 1}/{spec.n_actuators}] {name}: jog to the simulation's {zero_what} pose "
                "(0 rad), then press Enter"
            )
            u0 = _jog_units(arm, reader, i, deg_units)
            print(
                f"[{i + 1}/{spec.n_actuators}] {name}: jog to {refs[i]:+.3f} rad "
                f"({np.degrees(refs[i]):+.1f} deg) from there, then press Enter"
            )
            u1 = _jog_units(arm, reader, i, deg_units)
            cal = fit_joint(name, u0, u1, refs[i])
            joints.append(cal)
            print(
                f"  {name}: offset {cal.offset_units:.1f} {nominal.frame.units}, direction "
                f"{cal.direction:+d}, scale {cal.scale_units_per_rad:.2f} {nominal.frame.units}/rad"
            )
        result = ArmCalibration(
            arm_id=args.arm_id, protocol=args.protocol, frame=nominal.frame, joints=tuple(joints)
        )
        try:
            result.unit_limits(spec)
        except HardwareError as exc:
            raise CalibrationFileError(
                f"the measured calibration does not fit the spec: {exc}; nothing was written"
            ) from None
    result.save(out)
    print(f"saved {out}")
    return 0


def _find_port(args: argparse.Namespace) -> int:
    from serial.tools import list_ports

    def ports() -> dict[str, str]:
        return {p.device: f"{p.description} [{p.hwid}]" for p in list_ports.comports()}

    before = ports()
    if not args.unplug:
        if not before:
            print(
                "no serial ports found; plug the arm's USB adapter in (emulators: see `sim2real arm emulate`)"
            )
        for dev, desc in sorted(before.items()):
            print(f"{dev}\t{desc}")
        return 0
    reader = LineReader(sys.stdin.fileno())
    print(f"ports now: {', '.join(sorted(before)) or 'none'}")
    _prompt(reader, "unplug the arm's USB cable, then press Enter ", lambda: None)
    gone = sorted(set(before) - set(ports()))
    if len(gone) != 1:
        raise HardwareError(
            f"expected exactly one port to disappear, saw {gone or 'none'}; try again"
        )
    print(f"the arm is on {gone[0]}; plug it back in")
    return 0


def _gen_limits(args: argparse.Namespace) -> int:
    from hardware.firmware.limits import write_limits_header

    spec = _spec(args)
    cal = ArmCalibration.load(args.calibration) if args.calibration else None
    path = write_limits_header(Path(args.out), spec, cal, source=f"spec {args.spec or spec.name}")
    print(path)
    return 0


SUBCOMMANDS: dict[str, Callable[[argparse.Namespace], int]] = {
    "emulate": _emulate,
    "ping": _ping,
    "home": _home,
    "jog": _jog,
    "calibrate": _calibrate,
    "find-port": _find_port,
    "gen-limits": _gen_limits,
}


def run(args: argparse.Namespace) -> int:
    return SUBCOMMANDS[args.arm_command](args)
