"""The emulator: a real pty any serial program can open, servo dynamics, wire timing, baud
checks, fault injection, brown-out, unplug and the firmware watchdog."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import serial
from timescale import scaled

from hardware.emulator import Emulator, EmulatorConfig, FaultConfig
from hardware.emulator.dynamics import ServoBank, ServoParams
from hardware.errors import (
    DeviceResetError,
    HardwareError,
    NoReplyError,
    PortError,
    SafetyError,
    SpecError,
)
from hardware.firmware.limits import firmware_limits
from hardware.protocols import s2r
from hardware.protocols.s2r import S2RFramer, encode_frame
from hardware.serial_arm import SerialArm
from hardware.spec import ArmSpec


# ---- dynamics -----------------------------------------------------------------------------------
def _bank(spec: ArmSpec, **kw: float) -> ServoBank:
    return ServoBank(ServoParams.from_spec(spec, **kw), np.zeros(spec.n_actuators))


def test_rate_limit_lag_deadband_and_quantisation(spec: ArmSpec) -> None:
    dt = 0.001
    bank = _bank(spec)
    target = np.array([1.0, 0.0, 0.0, 0.0])
    on = np.ones(4, dtype=bool)
    speeds = []
    for _ in range(2000):
        bank.step(dt, target, on)
        speeds.append(bank.vel[0])
    assert max(speeds) <= spec.servo.max_speed_rad_s + 1e-9  # rate limit
    assert max(speeds) == pytest.approx(spec.servo.max_speed_rad_s)  # and it is reached
    assert abs(bank.pos[0] - 1.0) <= spec.servo.deadband_rad  # arrives, within the deadband
    # small step: pure first-order lag -> 63 % after one time constant
    bank = _bank(spec)
    small = np.array([0.05, 0.0, 0.0, 0.0])
    for _ in range(round(spec.servo.time_constant_s / dt)):
        bank.step(dt, small, on)
    assert bank.pos[0] == pytest.approx(0.05 * (1 - np.exp(-1)), rel=0.02)
    # inside the deadband nothing moves
    bank = _bank(spec)
    bank.step(0.1, np.full(4, spec.servo.deadband_rad * 0.9), on)
    assert np.all(bank.pos == 0.0)
    # unpowered servos do not move at all
    bank.step(0.1, np.ones(4), np.zeros(4, dtype=bool))
    assert np.all(bank.pos == 0.0)
    # readings are quantised to the resolution
    bank.pos = np.array([0.00123, 0.5, -0.3, 0.7])
    r = bank.reading_rad() / spec.servo.resolution_rad
    np.testing.assert_allclose(r, np.round(r), atol=1e-9)


def test_droop_and_noise(spec: ArmSpec) -> None:
    bank = ServoBank(
        ServoParams.from_spec(spec, droop_rad=0.03, noise_rad=0.01), np.zeros(4), seed=1
    )
    for _ in range(500):
        bank.step(0.002, np.zeros(4), np.ones(4, dtype=bool))
    # the pitch joints (shoulder, elbow) sag; yaw and gripper do not
    assert bank.pos[1] == pytest.approx(-0.03, abs=spec.servo.deadband_rad)
    assert bank.pos[2] == pytest.approx(-0.03, abs=spec.servo.deadband_rad)
    assert bank.pos[0] == 0.0 and bank.pos[3] == 0.0
    readings = np.array([bank.reading_rad()[0] for _ in range(400)])
    assert 0.006 < readings.std() < 0.014


def test_command_latency_shifts_the_response_by_exactly_the_dead_time(spec: ArmSpec) -> None:
    """A target received at t moves the horn as an undelayed one received at t + latency would;
    the delay is applied to the sub-step even when a due time falls inside a tick."""
    latency_s, tick_s = 0.0405, 0.002
    late = _bank(spec, command_latency_s=latency_s)
    plain = _bank(spec)
    on = np.ones(4, dtype=bool)
    step_at_s = 0.1
    target = np.array([0.5, -0.2, 0.05, 0.0])
    t_late, t_plain = [], []
    for k in range(300):
        t0, t1 = k * tick_s, (k + 1) * tick_s
        late.advance(t0, t1, target if t0 >= step_at_s else np.zeros(4), on)
        t_late.append(late.pos.copy())
    # the reference: the same target, undelayed, at the due time split inside its tick
    due_s = step_at_s + latency_s
    t = 0.0
    for k in range(300):
        t1 = (k + 1) * tick_s
        if t < due_s < t1:
            plain.step(due_s - t, np.zeros(4), on)
            plain.step(t1 - due_s, target, on)
        else:
            plain.step(t1 - t, target if t >= due_s else np.zeros(4), on)
        t = t1
        t_plain.append(plain.pos.copy())
    np.testing.assert_allclose(np.array(t_late), np.array(t_plain), atol=1e-12)
    first_move = int(np.argmax(np.abs(np.array(t_late)[:, 0]) > 0))
    assert (first_move + 1) * tick_s == pytest.approx(due_s, abs=tick_s)  # not at step_at_s
    late.drop_pending()  # a reboot forgets what was queued: the next target acts at once
    late.advance(0.6, 0.63, np.zeros(4), on)  # queued, it would not act before 0.6405 s
    assert late.pos[0] < 0.4


def test_command_latency_is_validated(spec: ArmSpec) -> None:
    with pytest.raises(HardwareError, match=r"command_latency_s must be finite and >= 0, got nan"):
        EmulatorConfig(command_latency_s=float("nan"))
    with pytest.raises(SpecError, match=r"command_latency_s must be finite and >= 0, got -0.01"):
        ServoParams.from_spec(spec, command_latency_s=-0.01)


@pytest.mark.realtime
def test_command_latency_over_the_pty(spec: ArmSpec) -> None:
    """Through a real pty and the Feetech device: the horn starts moving one latency after the
    device received the goal, neither before nor later. Judged on the emulator's clock (its
    device and servos step on a fixed grid), so a stalled test thread cannot move the bounds:
    a reading taken before the onset never shows motion, one after it always does."""
    latency_s, tick_s = 0.06, EmulatorConfig().tick_s
    with (
        Emulator(spec, "feetech", EmulatorConfig(command_latency_s=latency_s)) as emu,
        SerialArm(spec, emu.port, "feetech") as arm,
    ):
        arm.home()
        home = spec.actuator_home_rad
        assert emu.wait_until(lambda: bool(np.all(abs(emu.true_positions_rad() - home) < 0.02)))
        time.sleep(0.2)  # settled: nothing queued is still to come
        start = emu.true_positions_rad()
        goal = home.copy()
        goal[0] += 0.1
        still_at: list[float] = []  # emulator time just before a reading without motion
        moved_at = float("nan")  # ... and just after the first reading with motion
        arm.command(goal)
        deadline = time.monotonic() + scaled(10.0)
        while time.monotonic() < deadline:
            before = emu.now_s()
            moved = abs(emu.true_positions_rad()[0] - start[0]) > 1e-6
            if moved:
                moved_at = emu.now_s()
                break
            still_at.append(before)
        assert emu.sync()
        received_s = emu.applied("targets")[-1].t_s
    onset_s = received_s + latency_s
    assert moved_at >= onset_s - tick_s, (moved_at, onset_s)  # not before the latency
    # nor later: the device takes the goal on a tick, the servo steps on the next, and a
    # reading sees the last grid point before it: a few ticks of the emulator's own clock
    assert not still_at or max(still_at) <= onset_s + 5 * tick_s, (still_at[-3:], onset_s)


# ---- the pty ------------------------------------------------------------------------------------
def test_plain_pyserial_talks_to_it_and_link_is_cleaned_up(spec: ArmSpec, tmp_path: Path) -> None:
    link = tmp_path / "arm3"
    with Emulator(spec, "s2r", link=link) as emu:
        assert link.is_symlink() and os.readlink(link) == emu.device_path
        with serial.Serial(str(link), 115200, timeout=0.5) as port:
            port.write(b"\x00garbage\xa5" + encode_frame(9, s2r.PING))
            frames: list[s2r.S2RFrame] = []
            framer = S2RFramer()
            deadline = time.monotonic() + 2
            while not frames and time.monotonic() < deadline:
                frames = framer.feed(port.read(64), 0.0)
            assert frames and frames[0].seq == 9 and frames[0].type == s2r.PING | s2r.REPLY
            pong = s2r.PongPayload.decode(frames[0].payload)
            assert pong.n_actuators == spec.n_actuators and pong.watchdog_ms == 250
        assert emu.stats()["device_garbage_bytes"] == 9
        assert emu.true_positions_rad().shape == (spec.n_actuators,)
    assert not link.exists()


@pytest.mark.realtime
def test_wire_time_follows_the_baud(spec: ArmSpec, make_emulator: Callable[..., Emulator]) -> None:
    """The minimum of 30 round trips (load only ever adds time), at 19200 baud against 1 Mbaud:
    the wire time differs by 20 ms, far above what scheduling adds to the fastest trip."""

    def p50(baud: int) -> float:
        emu = make_emulator(spec, "s2r", EmulatorConfig(baud=baud))
        with SerialArm(spec, emu.port, baud=baud) as arm:
            arm.enable()
            times = []
            for _ in range(30):
                t = time.perf_counter()
                arm.command(spec.actuator_park_rad)
                times.append(time.perf_counter() - t)
        # The minimum, not the median: scheduling delays from other load only ever add time.
        return float(np.min(times))

    slow, fast = p50(19200), p50(1_000_000)
    request, reply = 8 + 2 * 4, 8 + 3 + 4 * 4
    wire_slow, wire_fast = (request + reply) * 10 / 19200, (request + reply) * 10 / 1_000_000
    assert slow >= wire_slow  # the bytes take that long on the wire
    assert slow - fast > 0.7 * (wire_slow - wire_fast)


def test_wrong_baud_gives_no_reply_with_a_baud_hint(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    emu = make_emulator(spec, "s2r")
    arm = SerialArm(spec, emu.port, baud=9600, timeout_s=0.02, retries=1)
    with pytest.raises(NoReplyError, match="baud rate.*9600 here; s2r devices default to 115200"):
        arm.connect()
    assert emu.sync(timeout_s=scaled(10.0))  # both tries reached the device, however late
    assert emu.stats()["baud_mismatch_chunks"] >= 2
    assert emu.host_baud == 9600


# ---- faults -------------------------------------------------------------------------------------
def test_corruption_and_drops_are_detected_and_never_applied(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    # a delayed reply (50 ms) outlives the host's 20 ms reply time-out: it arrives stale. The
    # retries are many, so a loaded machine's stall (up to 1 s) costs retries, never the run.
    faults = FaultConfig(
        corrupt_rate=0.1, drop_rate=0.1, delay_rate=0.02, delay_s=scaled(0.05), seed=3
    )
    emu = make_emulator(spec, "s2r", EmulatorConfig(baud=1_000_000, faults=faults))
    with SerialArm(
        spec, emu.port, baud=1_000_000, timeout_s=scaled(0.02), retries=50, host_watchdog_s=None
    ) as arm:
        arm.enable()
        emu.clear_log()
        rng = np.random.default_rng(0)
        sent = []
        for _ in range(300):
            goal = rng.uniform(spec.actuator_lower_rad, spec.actuator_upper_rad)
            arm.command(goal)
            sent.append(arm.last_sent_units)
        host = arm.stats()
    applied = [np.array(e.requested) for e in emu.applied("targets")]
    # exactly the commands the host sent, once each, in order: none lost, none corrupted,
    # no retransmission applied twice
    assert len(applied) == len(sent)
    assert all(np.array_equal(a, s) for a, s in zip(applied, sent, strict=True))
    st = emu.stats()
    injected = (
        st["rx_corrupted"]
        + st["rx_dropped"]
        + st["tx_corrupted"]
        + st["tx_dropped"]
        + st["tx_delayed"]
    )
    assert injected > 30
    assert st["device_crc_errors"] + st["device_header_errors"] + st["device_gap_resets"] > 0
    assert st["device_duplicates"] > 0  # retransmissions after a lost reply were recognised
    assert host["retries"] >= st["rx_corrupted"] + st["rx_dropped"] + st["tx_dropped"]
    assert host["rx_crc_errors"] + host["rx_header_errors"] + host["rx_garbage_bytes"] > 0
    assert host["stale_frames"] > 0  # the delayed replies arrived late and were discarded


def test_brownout_is_detected_and_enable_recovers(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    emu = make_emulator(spec, "s2r")
    with SerialArm(spec, emu.port) as arm:
        arm.enable()
        arm.command(spec.actuator_park_rad)
        emu.brownout()
        with pytest.raises(DeviceResetError, match="device reset detected.*boot id"):
            arm.command(spec.actuator_park_rad)
        # the link is alive: switched back on where it was, held and parked, torque on
        with pytest.raises(SafetyError, match="stopped after a fault.*reset"):
            arm.command(spec.actuator_park_rad)
        emu.sync()
        assert emu.torque_enabled().all()
        arm.enable()
        arm.command(spec.actuator_park_rad)
        assert emu.torque_enabled().all()
        limits = emu.applied("limits")
        assert len(limits) == 2  # the RAM limits were pushed again after the reboot


@pytest.mark.parametrize("protocol", ["feetech", "maestro"])
def test_brownout_on_bus_and_maestro(
    spec: ArmSpec, make_emulator: Callable[..., Emulator], protocol: str
) -> None:
    emu = make_emulator(spec, protocol)
    with SerialArm(spec, emu.port, protocol=protocol) as arm:
        arm.enable()
        arm.command(spec.actuator_park_rad)
        emu.sync()  # the command (no reply on these buses) has landed before the supply dips
        emu.brownout()
        with pytest.raises(DeviceResetError, match="rebooted"):
            arm.read_state()
        arm.enable()
        arm.command(spec.actuator_park_rad)
        emu.sync()
        assert emu.torque_enabled().all()


def test_unplugged_port_is_a_clear_error(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    emu = make_emulator(spec, "s2r")
    arm = SerialArm(spec, emu.port, timeout_s=0.02)
    arm.connect()
    arm.enable()
    emu.unplug()
    with pytest.raises((PortError, NoReplyError)) as info:
        for _ in range(20):
            arm.command(spec.actuator_park_rad)
            time.sleep(0.01)
    assert "\n" not in str(info.value)
    arm.close()  # closing after the port vanished does not raise


def test_cut_link_trips_the_firmware_watchdog(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    # the device's watchdog at 1 s: 20 back-to-back commands keep it fed on any machine. The
    # hold and detach times are the device's own (its grid), whenever the test thread looks.
    spec = replace(spec, safety=replace(spec.safety, watchdog_timeout_s=scaled(1.0)))
    emu = make_emulator(spec, "s2r")
    with SerialArm(spec, emu.port, host_watchdog_s=None, timeout_s=scaled(0.5)) as arm:
        arm.enable()
        goal = spec.actuator_park_rad.copy()
        for k in range(20):
            goal[0] = 0.02 * k
            arm.command(goal)
        last_rx = emu.applied("targets")[-1].t_s
        emu.cut()
        assert emu.wait_until(lambda: bool(emu.applied("watchdog_detach")), scaled(30.0))
        hold = emu.applied("watchdog_hold")[0].t_s
        detach = emu.applied("watchdog_detach")[0].t_s
        wd = spec.safety.watchdog_timeout_s
        # holds at the watchdog's timeout, to the firmware clock's 1 ms granularity either way
        assert wd - 0.001 <= hold - last_rx <= wd + 0.005
        assert detach - hold == pytest.approx(spec.safety.hold_before_disable_s, abs=0.005)
        assert not emu.torque_enabled().any()
        emu.restore()
        with pytest.raises(SafetyError, match="torque is off"):
            arm.command(goal)
        arm.enable()
        arm.command(goal)
        assert emu.torque_enabled().all()


def test_maestro_serial_timeout(spec: ArmSpec, make_emulator: Callable[..., Emulator]) -> None:
    # 0.5 s without a byte: enable and the command (back to back) never trip it on any machine;
    # the trip is waited for, not slept to
    timeout_s = scaled(0.5)
    emu = make_emulator(spec, "maestro", EmulatorConfig(maestro_serial_timeout_s=timeout_s))
    with SerialArm(spec, emu.port, protocol="maestro", host_watchdog_s=None) as arm:
        arm.enable()
        arm.command(spec.actuator_park_rad)
        assert emu.wait_until(lambda: not emu.torque_enabled().any(), timeout_s=scaled(10.0))
        with pytest.raises(SafetyError, match="serial timeout"):
            arm.read_state()


def test_bad_configuration_is_refused(spec: ArmSpec) -> None:
    with pytest.raises(HardwareError, match="valid: feetech, maestro, s2r"):
        Emulator(spec, "dynamixel")
    with pytest.raises(HardwareError, match="corrupt_rate"):
        FaultConfig(corrupt_rate=1.5)
    with pytest.raises(HardwareError, match="tick_s"):
        EmulatorConfig(tick_s=0.0)


def test_background_reader_swallows_line_noise(
    spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    emu = make_emulator(spec, "s2r", EmulatorConfig(baud=1_000_000))
    # a reply time-out no stall reaches: a retry here can only be a reply the noise cost
    with SerialArm(spec, emu.port, baud=1_000_000, timeout_s=scaled(5.0)) as arm:
        arm.enable()
        for _ in range(20):
            emu.inject_tx(bytes(range(0, 250, 3)) * 4)  # noise between replies
            arm.command(spec.actuator_park_rad)
        assert arm.stats()["rx_garbage_bytes"] > 20 * 100
        assert arm.stats()["retries"] == 0  # noise never cost a retry (nor a time-out waited)


# ---- idle: no wake-ups; lazy dynamics that do not depend on when anyone looks -------------------
@pytest.mark.parametrize("protocol", ["s2r", "feetech", "maestro"])
def test_an_idle_emulator_does_not_wake(
    spec: ArmSpec, make_emulator: Callable[..., Emulator], protocol: str
) -> None:
    emu = make_emulator(spec, protocol)
    with SerialArm(spec, emu.port, protocol=protocol, timeout_s=0.2) as arm:
        arm.enable()
        arm.command(spec.actuator_home_rad)
    assert emu.sync()
    before = emu._iterations
    time.sleep(0.3)
    emu.true_positions_rad()  # a reader integrates the motion itself: no wake-up needed
    assert emu._iterations == before  # no 2 ms tick: asleep until a byte or a deadline


def _replay_with_reads(spec: ArmSpec, reads_s: list[float]) -> np.ndarray:
    """The s2r device and servos driven by two frames, integrated at ``reads_s`` and at 0.6 s."""
    emu = Emulator(spec, "s2r")  # never started: times are given, not read from the clock
    device = emu._make_device(0.0)
    emu._device = device
    park = np.array(firmware_limits(spec).park_us)
    frames = {
        0.010: encode_frame(1, s2r.TORQUE, b"\x01"),
        0.020: encode_frame(2, s2r.SET_TARGETS, s2r.encode_targets(park + 150)),
    }
    with emu._lock:
        for t in sorted(set(reads_s) | set(frames) | {0.6}):
            emu._advance(t, exact=t in frames)  # a read stops at the grid; bytes split it
            if t in frames:
                device.receive(frames[t], t)
                emu._rx_at_s = t
    return emu.servos.pos.copy()


def test_lazy_dynamics_do_not_depend_on_when_anyone_looks(spec: ArmSpec) -> None:
    once = _replay_with_reads(spec, [])
    often = _replay_with_reads(spec, [k * 0.0013 for k in range(1, 400)])
    start = np.array(spec.actuator_park_rad)
    assert np.all(np.abs(once - start) > 0.2)  # it moved (150 us = 0.24 rad)
    np.testing.assert_allclose(often, once, atol=1e-9)


@pytest.mark.parametrize("feedback", ["measured", "commanded"])
def test_s2r_readings_follow_the_build(
    quick_spec: ArmSpec, make_emulator: Callable[..., Emulator], feedback: str
) -> None:
    """The firmware model in the build the spec asks for: with pots (measured) a jammed elbow
    reads where it is stuck; on bare PWM servos (commanded) it reads the pulse it was sent, and
    the STATE frame says which, so the host cannot mistake one for the other."""
    spec = quick_spec.with_feedback(feedback)
    emu = make_emulator(spec, "s2r")
    with SerialArm(spec, emu.port, protocol="s2r", host_watchdog_s=None) as arm:
        arm.enable()
        stuck = emu.true_positions_rad()[2]
        emu.jam("elbow")
        goal = arm.read_state().positions_rad.copy()
        goal[2] += 0.2
        for _ in range(40):
            arm.command(goal)
            time.sleep(0.01)

        def reading() -> tuple[np.ndarray, np.ndarray]:  # the raw reading: no stall watch
            us = arm.read_units()
            assert us.measured is not None
            return arm.calibration.from_units(us.positions), us.measured

        # commanded: the reading gets there; measured: half a second shows it never will
        wait_s = 2.0 if feedback == "commanded" else 0.5
        assert emu.wait_until(lambda: abs(reading()[0][2] - goal[2]) < 0.01, wait_s) == (
            feedback == "commanded"
        )
        positions, measured = reading()
        assert measured.tolist() == [feedback == "measured"] * spec.n_actuators
        assert emu.true_positions_rad()[2] == pytest.approx(stuck, abs=1e-9)  # it never moved
        if feedback == "measured":
            assert positions[2] == pytest.approx(stuck, abs=0.01)
        emu.jam()  # freed: it goes where it was told
        assert emu.wait_until(lambda: abs(emu.true_positions_rad()[2] - goal[2]) < 0.02)
    with pytest.raises(HardwareError, match=r"cannot jam \['wrist'\]"):
        emu.jam("wrist")
