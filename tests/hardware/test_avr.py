"""The arm3 firmware as the chip runs it: the sketch built for the ATmega328P, its size within
budget, and that very .elf in simavr behind a pty: the Arm contract, byte-stream replays against
the Python firmware model, measured pulse widths, the UART's real baud rate and a brown-out.

Without the Debian packages these tests skip with a one-line reason that says how to install them;
CI installs them (`make avr-deps`) and `.ci/run` fails if any test here was skipped.
"""

from __future__ import annotations

import itertools
import json
import os
import random
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import serial
from emulated import EmulatorProbe
from timescale import scaled

from hardware.emulator import FIRMWARES, AvrEmulator, Emulator, FirmwareCore
from hardware.emulator.firmware import AppliedCommand
from hardware.errors import HardwareError
from hardware.firmware import avr
from hardware.firmware.limits import firmware_limits
from hardware.protocols import s2r
from hardware.serial_arm import SerialArm
from hardware.spec import PWM_SPEC_PATH, ArmSpec, load_spec
from hardware.testing import CHECKS, SETTLE_TIMEOUT_S, ArmProbe

_MISSING = avr.missing_toolchain()
# CI sets SIM2REAL_REQUIRE_AVR=1: there a missing toolchain fails these tests instead
_REQUIRED = os.environ.get("SIM2REAL_REQUIRE_AVR") == "1"
pytestmark = pytest.mark.skipif(_MISSING is not None and not _REQUIRED, reason=_MISSING or "")


@pytest.fixture(scope="session")
def avr_build() -> avr.AvrBuild:
    return avr.build()


@pytest.fixture
def make_avr(avr_build: avr.AvrBuild) -> Iterator[Callable[..., AvrEmulator]]:
    made: list[AvrEmulator] = []

    def factory(*args: object, **kwargs: object) -> AvrEmulator:
        emu = AvrEmulator(*args, **kwargs)  # type: ignore[arg-type]
        emu.start()
        made.append(emu)
        return emu

    yield factory
    for emu in made:
        emu.stop()


def test_registry_names_both_firmwares() -> None:
    assert {"python": Emulator, "avr": AvrEmulator} == FIRMWARES
    with pytest.raises(HardwareError, match="speaks protocol 's2r', not 'maestro'"):
        AvrEmulator(protocol="maestro")


def test_sketch_fits_the_chip_with_headroom(avr_build: avr.AvrBuild) -> None:
    report = avr.size_report(avr_build.elf)
    assert 2_000 < report.flash_bytes <= avr.BUDGET * report.flash_total_bytes
    assert 100 < report.ram_static_bytes <= avr.BUDGET * report.ram_total_bytes
    assert avr_build.harness.exists()


@pytest.fixture(scope="session")
def avr_spec(quick_spec: ArmSpec) -> ArmSpec:
    """quick_spec with a 2 s watchdog (host and chip, scaled): these tests wait for the chip's
    pulses to settle (``sync``), which on a loaded machine may take longer than 0.25 s between
    commands. The watchdog itself is covered by the byte-stream replays."""
    return replace(quick_spec, safety=replace(quick_spec.safety, watchdog_timeout_s=scaled(2.0)))


@pytest.fixture(scope="session")
def avr_pwm_spec(avr_spec: ArmSpec) -> ArmSpec:
    """avr_spec on bare PWM servos: the committed build, whose readings are the outputs."""
    return avr_spec.with_feedback("commanded")


class TestAvrContract:
    """The same contract (``hardware.testing``) as the Python emulator's, against the .elf in
    simavr."""

    @pytest.fixture
    def emulator(self, avr_spec: ArmSpec, make_avr: Callable[..., AvrEmulator]) -> AvrEmulator:
        return make_avr(avr_spec)

    @pytest.fixture
    def arm(self, avr_spec: ArmSpec, emulator: AvrEmulator) -> Iterator[SerialArm]:
        arm = SerialArm(avr_spec, emulator.port, protocol="s2r", timeout_s=scaled(0.5))
        yield arm
        arm.close()

    @pytest.fixture
    def probe(self, arm: SerialArm, emulator: AvrEmulator) -> ArmProbe:
        return EmulatorProbe(emulator, arm.calibration)  # type: ignore[arg-type]

    @pytest.mark.parametrize("check", CHECKS)
    def test_contract(self, check: str, arm: SerialArm, probe: ArmProbe) -> None:
        CHECKS[check](arm, probe, settle_timeout_s=scaled(SETTLE_TIMEOUT_S))


class TestAvrPwmContract(TestAvrContract):
    """The committed build on bare PWM servos: every reading is the commanded pulse."""

    @pytest.fixture
    def emulator(self, avr_pwm_spec: ArmSpec, make_avr: Callable[..., AvrEmulator]) -> AvrEmulator:
        return make_avr(avr_pwm_spec)

    @pytest.fixture
    def arm(self, avr_pwm_spec: ArmSpec, emulator: AvrEmulator) -> Iterator[SerialArm]:
        arm = SerialArm(avr_pwm_spec, emulator.port, protocol="s2r", timeout_s=scaled(0.5))
        yield arm
        arm.close()


def test_pulses_are_the_firmware_outputs_and_stop_when_detached(
    avr_pwm_spec: ArmSpec, make_avr: Callable[..., AvrEmulator]
) -> None:
    avr_spec = avr_pwm_spec  # readings are the outputs: compare them with the pins
    emu = make_avr(avr_spec)
    limits = firmware_limits(avr_spec)
    with SerialArm(avr_spec, emu.port, protocol="s2r", timeout_s=0.2) as arm:
        arm.enable()
        goal = avr_spec.actuator_home_rad
        arm.move_to(goal, tolerance_rad=0.01)
        emu.sync()
        state = arm.read_state()
        outputs = arm.calibration.to_units(state.positions_rad)
        # the widths measured on the pins are the core's outputs, to the microsecond
        assert emu.wait_until(lambda: np.array_equal(emu.pulse_widths_us(), outputs))
        assert np.all(emu.torque_enabled())
        assert np.all(outputs >= limits.lower_us) and np.all(outputs <= limits.upper_us)
        # hold still: every pulse from now on should be the output, edge to edge
        t_steady = emu.now_s()
        for _ in range(10):
            arm.hold()
            time.sleep(0.02)
        emu.sync()
        steady = [(ch, w) for t, ch, w in emu.pulses() if t > t_steady + 0.005]
        arm.disable()
        emu.sync()
        assert not np.any(emu.torque_enabled())
    # both edges of a pulse come from Timer1 compare instants: the width is the output to within
    # a fraction of a microsecond, except when another interrupt (millis, UART) delayed an edge
    off_ns = np.array([abs(w - 1000 * int(outputs[ch])) for ch, w in steady])
    assert len(off_ns) > 20
    assert np.median(off_ns) < 500 and np.mean(off_ns < 500) > 0.8 and off_ns.max() < 20_000


def test_uart_runs_at_the_uno_baud_rate_and_the_stack_fits(
    avr_spec: ArmSpec, make_avr: Callable[..., AvrEmulator], avr_build: avr.AvrBuild
) -> None:
    emu = make_avr(avr_spec)
    with SerialArm(avr_spec, emu.port, protocol="s2r", timeout_s=0.2) as arm:
        arm.enable()
        for _ in range(5):
            arm.command(avr_spec.actuator_home_rad)
    assert emu.baud_actual is not None
    # U2X with UBRR 16: 117,647 baud, +2.1 % from 115,200 (a UART tolerates about 4.5 %)
    assert emu.baud_actual == pytest.approx(117_647, abs=1)
    peak = emu.stack_peak_bytes()
    assert peak is not None and 20 < peak < 1024
    report = avr.size_report(avr_build.elf, stack_peak_bytes=peak)
    assert report.ram_fraction <= avr.BUDGET, report.as_dict()


def test_brownout_gives_a_new_boot_id_and_limp_servos(
    avr_spec: ArmSpec, make_avr: Callable[..., AvrEmulator]
) -> None:
    emu = make_avr(avr_spec)
    with SerialArm(avr_spec, emu.port, protocol="s2r", timeout_s=0.2) as arm:
        arm.enable()
        arm.command(avr_spec.actuator_home_rad)
        emu.sync()
        assert np.all(emu.torque_enabled())
        emu.brownout()
        assert emu.wait_until(lambda: bool(emu.applied("reset")))
        emu.sync()
        assert not np.any(emu.torque_enabled())
        with pytest.raises(Exception, match="reset"):
            arm.read_state()


# ---- byte-stream replay: the AVR binary vs the Python model -------------------------------------
def _traffic(seed: int, n: int) -> list[tuple[float, bytes]]:
    """Protocol-shaped chunks with the pause before each, on the chip's clock. Every pause stays
    far from a firmware time threshold (10 ms gap, 250 ms watchdog, 500 ms hold) and every
    reply that carries the output pulses comes after the slew finished, so no reply depends on
    which millisecond a byte landed in: the model and the chip must agree byte for byte.

    Thirty chunks: the first thirteen are every kind once (targets twice) in a shuffled order;
    a hold, a detach and a cut frame come at fixed places; the last reads the state (the pot
    build's wipers moved half-way through); the rest are drawn by weight."""
    rng = random.Random(seed)
    # one draw inside each kind's band below, so that each kind comes at least once
    every_kind = [0.1, 0.2, 0.32, 0.35, 0.4, 0.48, 0.52, 0.56, 0.6, 0.64, 0.7, 0.78, 0.9]
    rng.shuffle(every_kind)
    long_pause_at = {5: 0.45, 17: 1.0}  # the watchdog: hold; hold, then detach
    seq = 0

    def frame(msg: int, payload: bytes) -> bytes:
        nonlocal seq
        seq = (seq + 1) & 0xFF
        return s2r.encode_frame(seq, msg, payload)

    out: list[tuple[float, bytes]] = [(0.3, frame(s2r.TORQUE, b"\x01"))]
    last = b""
    settle = False  # a target may have changed: let the slew finish before the next chunk
    for i in range(30):
        kind = every_kind[i] if i < len(every_kind) else 0.4 if i == 29 else rng.random()
        moves = False
        if kind < 0.30:
            payload = b"".join(rng.randrange(300, 2700).to_bytes(2, "little") for _ in range(n))
            data, moves = frame(s2r.SET_TARGETS, payload), True
        elif kind < 0.34:
            data = frame(s2r.TORQUE, bytes((rng.choice([0, 1, 1, 1, 2]),)))
        elif kind < 0.36:  # torque on with start pulses (protocol 2), now and then malformed
            starts = [rng.randrange(300, 2700) for _ in range(n)]
            on = bytes((rng.choice([1, 1, 0]),))
            data = frame(s2r.TORQUE, on + s2r.encode_targets(starts)[: rng.choice([2 * n, 3])])
            moves = True
        elif kind < 0.46:
            data = frame(s2r.READ_STATE, b"")
        elif kind < 0.50:
            data = frame(s2r.PING, b"")
        elif kind < 0.54:
            data = frame(s2r.GET_STATS, b"")
        elif kind < 0.58:
            vals = []
            for _ in range(n):
                lo = rng.randrange(400, 1500)
                vals += [lo, lo + rng.randrange(1, 1200), rng.randrange(0, 200)]
            data = frame(s2r.SET_LIMITS, b"".join(v.to_bytes(2, "little") for v in vals))
            moves = True
        elif kind < 0.62:
            data = frame(s2r.HEARTBEAT, b"")
        elif kind < 0.66:
            data = frame(rng.randrange(8, 0x7F), b"")
        elif kind < 0.74:
            data, moves = last, True  # a retransmission
        elif kind < 0.82:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 12)))  # garbage
        else:
            broken = bytearray(frame(s2r.SET_TARGETS, bytes(2 * n)))
            broken[rng.randrange(len(broken))] ^= rng.randrange(1, 256)
            data = bytes(broken)
        if settle:  # heartbeats (timing-free ACKs) keep the watchdog fed while the slew ends
            out += [(0.1, frame(s2r.HEARTBEAT, b"")) for _ in range(5)]
        pause = rng.choice([0.02, 0.03, 0.05])
        if i in long_pause_at or rng.random() < 0.08:  # watchdog: hold, or hold then detach
            pause = max(pause, long_pause_at.get(i) or rng.choice([0.45, 1.0]))
        if (i == 9 or rng.random() < 0.1) and len(data) > 2:  # a frame cut, resumed or not
            cut = rng.randrange(1, len(data))
            out.append((pause, data[:cut]))
            pause, data = rng.choice([0.0, 0.05]), data[cut:]
        out.append((pause, data))
        last = data
        settle = moves
    out.append((0.3, frame(s2r.GET_STATS, b"")))
    return out


def _model_replay(
    traffic: list[tuple[str, float, bytes]],
    spec: ArmSpec,
    boot_id: int,
    pots: Sequence[tuple[float, int, int]] = (),
) -> tuple[list[bytes], list[AppliedCommand]]:
    """What the Python model does with the bytes the chip received, at the chip's times, with
    the potentiometer readings the chip's ADC saw (``AvrEmulator.adc_readings``)."""
    log: list[AppliedCommand] = []
    core = FirmwareCore(firmware_limits(spec), boot_id, now_ms=0, on_log=log.append)
    replies: list[bytes] = []
    now_ms = 0
    events = sorted(
        [(t, 0, ("RX", data)) for direction, t, data in traffic if direction == "RX"]
        + [(t, 1, ("A", (i, counts))) for t, i, counts in pots],
        key=lambda e: (e[0], e[1]),
    )
    for t_s, _, (_kind, value) in events:
        if isinstance(value, tuple):
            core.set_pot(*value)
            continue
        ms = int(t_s * 1000)
        while now_ms < ms:  # the chip's loop ticks every millisecond
            now_ms += 1
            core.tick(now_ms)
        replies += core.feed(value, ms)
        core.tick(ms)
    return replies, log


def _pause_on_the_chips_clock(emu: AvrEmulator, sent_bytes: int, pause_s: float) -> None:
    """Wait until the chip has taken every byte sent so far and then run ``pause_s`` of its own
    time: a starved simulator runs slower than the wall, and a wall-clock pause would reach it
    shorter, near a firmware threshold (a 20 ms pause read as the 10 ms frame gap)."""

    def received() -> tuple[int, float]:
        rx = [(t, len(d)) for k, t, d in emu.uart_traffic() if k == "RX"]
        return sum(n for _, n in rx), max((t for t, _ in rx), default=0.0)

    assert emu.wait_until(lambda: received()[0] >= sent_bytes, scaled(10.0)), (
        f"the chip did not take the {sent_bytes} bytes sent"
    )
    after_s = received()[1] + pause_s
    assert emu.wait_until(lambda: emu.now_s() >= after_s, scaled(10.0)), (
        f"the chip's clock stopped before {after_s:.3f} s"
    )


def _move_wipers_quietly(emu: AvrEmulator, counts: dict[str, int]) -> None:
    """Move wipers between frames, on the chip's clock rather than the wall's: every byte sent
    so far is processed first, and the next is sent only once the chip's ADC has read each new
    voltage, so no frame is handled while a reading changes (a loaded machine slows the chip
    as much as it likes)."""
    assert emu.sync(timeout_s=scaled(10.0)), "the chip did not catch up with the bytes sent"
    seen = len(emu.adc_readings())
    for name, value in counts.items():
        emu.set_pot_counts(name, value)
    wanted = {emu.spec.actuator_names.index(n): v for n, v in counts.items()}

    def read_back() -> bool:
        new = emu.adc_readings()[seen:]
        return all(any(i == j and c == v for _, i, c in new) for j, v in wanted.items())

    assert emu.wait_until(read_back, timeout_s=scaled(10.0)), f"the ADC never read {counts}"
    assert emu.sync(timeout_s=scaled(10.0))


# (traffic seed, build): the replays of ``test_avr_binary_matches_the_python_model``
REPLAYS = ((1, "pwm"), (2, "pwm"), (3, "pots"))


def test_avr_binary_matches_the_python_model(
    spec: ArmSpec, make_avr: Callable[..., AvrEmulator]
) -> None:
    """Byte for byte, in both builds: bare PWM servos (readings commanded: the output pulses)
    and every potentiometer wired (readings measured). In the pot build the test holds each
    wiper at a voltage of its own and moves two of them half-way, each change in a quiet
    moment of the stream, so the chip's ADC and the model read the same counts.

    The replays run side by side, a chip each: each is ~8 s of paced traffic and a few per
    cent of a core, and no reply depends on the wall clock (``_traffic``)."""
    chips = {(seed, build): make_avr(_build_spec(spec, build)) for seed, build in REPLAYS}
    failures: dict[tuple[int, str], BaseException] = {}

    def replay(case: tuple[int, str]) -> None:
        try:
            _replay_matches_the_model(spec, chips[case], *case)
        except BaseException as exc:  # reported below, with its replay
            failures[case] = exc

    workers = [threading.Thread(target=replay, args=(case,), daemon=True) for case in REPLAYS]
    for w in workers:
        w.start()
    for w in workers:
        w.join(timeout=scaled(300.0))  # only turns a hang into a failure
    hung = [case for case, w in zip(REPLAYS, workers, strict=True) if w.is_alive()]
    assert not hung, f"replays that never finished: {hung}"
    assert not failures, "; ".join(
        f"replay seed {seed}, {build} build: {type(exc).__name__}: {exc}"
        for (seed, build), exc in failures.items()
    )


def _build_spec(spec: ArmSpec, build: str) -> ArmSpec:
    return load_spec(PWM_SPEC_PATH) if build == "pwm" else spec


def _replay_matches_the_model(spec: ArmSpec, emu: AvrEmulator, seed: int, build: str) -> None:
    build_spec = emu.spec
    names = build_spec.actuator_names
    pinned = {name: 300 + 90 * i for i, name in enumerate(names)} if build == "pots" else {}
    for name, counts in pinned.items():
        emu.set_pot_counts(name, counts)
    chunks = _traffic(seed, spec.n_actuators)
    half = len(chunks) // 2
    sent_bytes = 0
    with serial.Serial(emu.port, 115200, timeout=0) as port:
        for k, (pause, data) in enumerate(chunks):
            if k == half and pinned:  # a quiet moment: no frame in flight, none due soon
                _move_wipers_quietly(emu, {names[0]: 800, names[2]: 1020})  # 1020: clamped
            if pause > 0:
                _pause_on_the_chips_clock(emu, sent_bytes, pause)
            port.write(data)
            sent_bytes += len(data)
            port.read(4096)  # keep the line drained
        assert emu.sync(timeout_s=scaled(10.0)), "the chip did not catch up with the bytes sent"
        time.sleep(0.05)
        port.read(4096)
    traffic = emu.uart_traffic()
    sent = b"".join(d for _, d in chunks)
    assert b"".join(d for k, _, d in traffic if k == "RX") == sent
    framer = s2r.S2RFramer(gap_s=1.0)
    chip_replies = [
        s2r.encode_frame(f.seq, f.type, f.payload)
        for k, t, d in traffic
        if k == "TX"
        for f in framer.feed(d, t)
    ]
    model_replies, model_log = _model_replay(
        traffic, build_spec, boot_id=1, pots=emu.adc_readings()
    )
    assert len(chip_replies) == len(model_replies) > 20
    for k, (a, b) in enumerate(zip(chip_replies, model_replies, strict=True)):
        assert a == b, f"reply {k}: chip {a.hex()} != model {b.hex()}"
    chip_targets = [(e.requested, e.applied) for e in emu.applied("targets")]
    model_targets = [(e.requested, e.applied) for e in model_log if e.kind == "targets"]
    assert chip_targets == model_targets and chip_targets
    assert [e.applied for e in emu.applied("torque")] == [
        e.applied for e in model_log if e.kind == "torque"
    ]
    # the traffic exercised errors, clamps and retransmissions
    assert any(r[5] == s2r.ERROR for r in chip_replies)
    stats = s2r.decode_stats(chip_replies[-1][6:-2])
    assert stats["clamps"] > 0 and stats["garbage_bytes"] > 0
    # every STATE said which readings are measured; in the pot build they are the wipers
    states = [
        s2r.StatePayload.decode(r[6:-2], spec.n_actuators)
        for r in chip_replies
        if r[5] in (s2r.SET_TARGETS | s2r.REPLY, s2r.READ_STATE | s2r.REPLY)
    ]
    assert states and {st.measured for st in states} == {0 if build == "pwm" else 0b1111}
    if pinned:
        limits = firmware_limits(build_spec)
        seen = {st.positions for st in states}
        before = tuple(limits.pot_us(i, pinned[n]) for i, n in enumerate(names))
        after = (limits.pot_us(0, 800), before[1], limits.pot_us(2, 1020), before[3])
        assert seen == {before, after} and after[2] == limits.pot_us_max  # clamped to the span


def test_a_spec_with_other_limits_gets_its_own_build(quick_spec: ArmSpec, tmp_path: Path) -> None:
    # quick_spec holds 50 ms instead of 500: another limits.h, another .elf
    result = avr.build(quick_spec)
    assert result.limits_crc == firmware_limits(quick_spec).crc
    assert result.elf.parent.name == f"avr-{result.limits_crc:04x}"
    assert "#define ARM3_HOLD_MS 50" in (result.elf.parent / "limits.h").read_text()


def test_cli_emulate_serves_the_avr_firmware(spec: ArmSpec, tmp_path: Path) -> None:
    import signal
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[2]
    link, log = tmp_path / "arm3", tmp_path / "log.jsonl"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim2real", "arm", "emulate", "--firmware", "avr"]
        + ["--link", str(link), "--log", str(log)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(root)),
        cwd=root,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == str(link)
        with SerialArm(spec, str(link), protocol="s2r", timeout_s=0.2) as arm:
            assert arm.info is not None and "arm3 firmware" in arm.info.description
            state = arm.home()
            np.testing.assert_allclose(state.positions_rad, spec.actuator_home_rad, atol=0.06)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert not link.exists()
    kinds = [json.loads(line)["kind"] for line in log.read_text().splitlines()]
    assert "targets" in kinds and kinds[-1] == "torque"


def test_gripper_pulses_on_its_own_pin(
    avr_spec: ArmSpec, make_avr: Callable[..., AvrEmulator]
) -> None:
    gripper = avr_spec.gripper
    assert gripper is not None
    g = avr_spec.n_actuators - 1
    emu = make_avr(avr_spec)
    with SerialArm(avr_spec, emu.port, protocol="s2r", timeout_s=0.2) as arm:
        arm.enable()
        goal = arm.read_state().positions_rad.copy()
        goal[g] = gripper.open_rad + 1.0  # beyond the limit: clamped on the host and the chip
        for _ in range(60):
            sent = arm.command(goal)
            time.sleep(0.01)
        assert sent[g] == pytest.approx(gripper.open_rad, abs=0.005)
        units = int(arm.calibration.to_units(sent)[g])
        assert units <= firmware_limits(avr_spec).upper_us[g]
        assert emu.wait_until(lambda: emu.pulse_widths_us()[g] == units)
        assert emu.applied("targets")[-1].applied[g] == units
        assert emu.true_positions_rad()[g] == pytest.approx(gripper.open_rad, abs=0.05)


def test_slew_and_watchdog_run_in_chip_time(
    spec: ArmSpec, make_avr: Callable[..., AvrEmulator]
) -> None:
    """In simulated 16 MHz time (not wall time): the output pulse slews at the compiled rate, and
    with the host silent the chip holds after 250 ms and stops the pulses 500 ms later. The
    committed build (no pots): torque on starts the outputs at park."""
    spec = load_spec(PWM_SPEC_PATH)
    limits = firmware_limits(spec)
    emu = make_avr(spec)
    target = list(limits.park_us)
    target[0] += 150
    with serial.Serial(emu.port, 115200, timeout=0.5) as port:
        port.write(s2r.encode_frame(1, s2r.TORQUE, b"\x01"))
        assert len(port.read(8)) == 8
        time.sleep(0.1)
        port.write(s2r.encode_frame(2, s2r.SET_TARGETS, s2r.encode_targets(target)))
        assert len(port.read(8 + 3 + 4 * spec.n_actuators)) > 0
        # then silence: the chip's watchdog, not the host's, ends it
        assert emu.wait_until(lambda: len(emu.pulse_stops()) == spec.n_actuators, timeout_s=5.0)
    replies = [t for k, t, d in emu.uart_traffic() if k == "TX"]
    t_cmd = replies[-1]  # the STATE reply: the target was applied just before it
    # the harness stamps the reply's bytes as it collects them, anywhere within their time on the
    # wire (later on a loaded machine, where the chip's loop collects bigger chunks)
    wire_s = (8 + 3 + 4 * spec.n_actuators) * 10 / 115200
    ch0 = [(t, w) for t, ch, w in emu.pulses() if ch == 0 and t > t_cmd]
    reached = next(t for t, w in ch0 if round(w / 1000) == target[0])
    slew_s = 150 / limits.slew_us_per_s[0]  # 31.4 ms at 4,774 us/s
    # + one 20 ms frame + a pulse
    assert slew_s - 0.002 - wire_s <= reached - t_cmd <= slew_s + 0.025
    # 150 us in steps no bigger than one 20 ms frame's worth of slew
    widths = [w / 1000 for _, w in ch0 if w / 1000 <= target[0] + 1]
    assert max(b - a for a, b in itertools.pairwise(widths)) <= (limits.slew_us_per_s[0] * 0.021)
    off_s = min(t for t, _ in emu.pulse_stops()) - t_cmd
    wd_s = (limits.watchdog_ms + limits.hold_ms) / 1000  # 750 ms
    assert wd_s - 0.002 - wire_s <= off_s <= wd_s + 0.025  # stopped between two frames
    # while holding, the pulses stayed at the output: no motion after the hold
    assert all(round(w / 1000) == target[0] for t, w in ch0 if t > reached)
