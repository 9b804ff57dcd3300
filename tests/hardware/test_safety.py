"""Safety: the filter, the workspace guard, the host watchdog, e-stop on signals, and the property
that no command outside the limits, over the step clamp or outside the workspace ever reaches a
device.

The property runs in-process (SafetyFilter -> unit quantisation -> the protocol's real encoder ->
the emulated device's real decoder and apply path): 2,000 cases for s2r and 1,000 each for feetech
and maestro in the default run, and 10,000 cases for s2r under the ``slow`` marker (about 20 s here: ``pytest -m slow``). A smaller
property runs end to end through SerialArm and the emulator over a real pty.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from timescale import scaled

from hardware.emulator import AppliedCommand, Emulator, EmulatorConfig, FirmwareCore
from hardware.emulator.devices import FeetechDevice, MaestroDevice
from hardware.emulator.dynamics import ServoBank, ServoParams
from hardware.errors import SafetyError, SpecError
from hardware.firmware.limits import firmware_limits
from hardware.joint_calibration import ArmCalibration, nominal_calibration
from hardware.protocols import PROTOCOLS, s2r
from hardware.protocols.feetech import goal_packet
from hardware.protocols.maestro import targets_packet
from hardware.safety import SafetyFilter, Watchdog, WorkspaceGuard
from hardware.serial_arm import SerialArm, quantise_targets
from hardware.spec import DEFAULT_SPEC_PATH, ArmSpec, load_spec

NASTY = [math.nan, math.inf, -math.inf, 1e9, -1e9, 1e300, -1e300, 0.0]
value_st = st.one_of(st.sampled_from(NASTY), st.floats(allow_nan=True, allow_infinity=True))
command_st = st.tuples(value_st, value_st, value_st, value_st)
sequence_st = st.lists(command_st, min_size=1, max_size=8)
EPS = 1e-9
ROUNDING_M = 5e-4  # what a device receives is the filter's output rounded to servo units


# ---- the filter -----------------------------------------------------------------------------
def test_filter_order_and_policy(spec: ArmSpec) -> None:
    f = SafetyFilter(spec)
    lo, hi, step = spec.actuator_lower_rad, spec.actuator_upper_rad, spec.safety.max_step_rad
    prev = spec.actuator_home_rad.copy()
    out = f.filter([math.nan, 1e9, -math.inf, prev[3]], prev)
    assert out[0] == prev[0]  # NaN: held
    assert out[1] == pytest.approx(prev[1] + step)  # 1e9: limit, then one step
    assert out[2] == prev[2]  # -inf: held
    assert f.stats.nonfinite == 1 and f.stats.limit_clamped == 1 and f.stats.step_clamped == 1
    # a target inside the limits and within a step goes through unchanged
    near = prev + 0.1
    np.testing.assert_array_equal(f.filter(near, prev), np.clip(near, lo, hi))
    # the previous target itself is brought inside the limits first
    out = f.filter(hi + 5, hi + 5)
    assert np.all(out <= hi)


def test_filter_refuses_bad_shapes_and_settings(spec: ArmSpec) -> None:
    f = SafetyFilter(spec)
    for bad in ([1.0, 2.0], np.zeros((4, 1)), "x", None, [object()] * 4):
        with pytest.raises(SafetyError, match="targets must"):
            f.filter(bad, spec.actuator_home_rad)
    with pytest.raises(SafetyError, match="cannot be switched off"):
        SafetyFilter(spec, max_step_rad=math.inf)
    with pytest.raises(SafetyError, match="cannot be switched off"):
        SafetyFilter(spec, max_step_rad=0.0)
    with pytest.raises(SafetyError, match="hold, raise"):
        SafetyFilter(spec, on_nonfinite="ignore")
    strict = SafetyFilter(spec, on_nonfinite="raise")
    with pytest.raises(SafetyError, match="non-finite target.*elbow"):
        strict.filter([0.0, 0.0, math.nan, 0.0], spec.actuator_home_rad)


def test_clamp_is_on_by_default(spec: ArmSpec) -> None:
    f = SafetyFilter(spec)
    assert f.max_step_rad == spec.safety.max_step_rad > 0


# ---- the workspace guard ------------------------------------------------------------------------
SPEC = load_spec()
GUARD = WorkspaceGuard(SPEC)
joint_st = st.tuples(
    *(
        st.floats(float(lo), float(hi))
        for lo, hi in zip(SPEC.lower_rad, SPEC.upper_rad, strict=True)
    )
)
actuator_st = st.tuples(
    *(
        st.floats(float(lo), float(hi))
        for lo, hi in zip(SPEC.actuator_lower_rad, SPEC.actuator_upper_rad, strict=True)
    )
)
safe_st = actuator_st.filter(lambda q: GUARD.inside(q))
unsafe_st = actuator_st.filter(lambda q: not GUARD.inside(q))
FAST = settings(
    max_examples=300, deadline=None, database=None, suppress_health_check=list(HealthCheck)
)


def _reference_excess_m(spec: ArmSpec, q: np.ndarray) -> float:
    """The guard's measure from the spec's own FK (numpy): the reference the fast path matches."""
    lo, hi = spec.workspace_box_m()
    floor = spec.workspace.table_z_m + spec.workspace.margin_m
    points = (spec.forward_kinematics(q[:3]), spec.elbow_position(q[:3]))
    return max(max(floor - p[2], *(lo - p), *(p - hi)) for p in points)


@FAST
@given(q=joint_st)
def test_guard_fk_is_the_spec_fk(q: tuple[float, ...]) -> None:
    qa = np.array(q)
    assert GUARD.excess_m(qa) == pytest.approx(_reference_excess_m(SPEC, qa), abs=1e-12)
    assert GUARD.inside(qa) == (SPEC.workspace_violation(qa) == "")


def test_the_guard_has_work_to_do_in_the_shipped_spec() -> None:
    """About one joint-space sample in eight puts the tool under the floor: the guard is not
    vacuous, and the park and home poses are inside it."""
    rng = np.random.default_rng(0)
    q = rng.uniform(SPEC.lower_rad, SPEC.upper_rad, size=(4000, 3))
    outside = np.mean([not GUARD.inside(x) for x in q])
    assert 0.05 < outside < 0.3
    assert GUARD.inside(SPEC.park_rad) and GUARD.inside(SPEC.home_rad)


@settings(max_examples=1000, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(start=safe_st, commands=sequence_st)
def test_random_commands_never_leave_the_workspace(
    start: tuple[float, ...], commands: list[tuple[float, ...]]
) -> None:
    """Arbitrary outputs (NaN, inf, 1e300, anything) from any safe pose: every filtered command
    keeps the tool and the elbow above the table + margin and inside the box (by the spec's own
    FK), inside the limits and within one step."""
    f = SafetyFilter(SPEC)
    prev = np.array(start)
    for c in commands:
        out = f.filter(np.array(c), prev)
        assert SPEC.workspace_violation(out[:3]) == "", (prev, c, out)
        assert np.all(out >= SPEC.actuator_lower_rad) and np.all(out <= SPEC.actuator_upper_rad)
        assert np.all(np.abs(out - prev) <= f.max_step_rad + EPS)
        prev = out


@FAST
@given(start=unsafe_st, command=command_st)
def test_from_outside_a_command_never_goes_further_out(
    start: tuple[float, ...], command: tuple[float, ...]
) -> None:
    """An arm switched on where it was left (below the floor) can be driven back, never deeper."""
    f = SafetyFilter(SPEC)
    prev = np.array(start)
    out = f.filter(np.array(command), prev)
    assert GUARD.excess_m(out) <= GUARD.excess_m(prev) + 1e-12


@FAST
@given(start=safe_st, delta=st.tuples(*[st.floats(-0.25, 0.25)] * 4))
def test_safe_commands_pass_unchanged(start: tuple[float, ...], delta: tuple[float, ...]) -> None:
    f = SafetyFilter(SPEC)
    prev = np.array(start)
    target = prev + np.array(delta)
    inside_limits = np.all(target >= SPEC.actuator_lower_rad) and np.all(
        target <= SPEC.actuator_upper_rad
    )
    if not (inside_limits and GUARD.inside(target)):
        return
    np.testing.assert_array_equal(f.filter(target, prev), target)
    assert f.stats.workspace_clamped == 0 and f.stats.step_clamped == 0


def test_a_dive_into_the_table_is_held_and_counted() -> None:
    """Shoulder forward, forearm straight down: the guard shortens the steps, the tool stops on
    the floor, the gripper still moves, and the stats count every command it changed."""
    f = SafetyFilter(SPEC)
    prev = SPEC.actuator_home_rad.copy()
    dive = np.array([0.0, 1.3, 0.27, SPEC.gripper.closed_rad if SPEC.gripper else 0.0])
    assert not GUARD.inside(dive)
    for _ in range(40):
        prev = f.filter(dive, prev)
    floor = SPEC.workspace.table_z_m + SPEC.workspace.margin_m
    tool_z = SPEC.forward_kinematics(prev[:3])[2]
    assert floor <= tool_z < floor + 0.002  # it stopped on the floor, not short of it
    assert prev[3] == dive[3]
    assert f.stats.workspace_clamped > 0
    assert f.stats.commands == 40


@FAST
@given(start=safe_st)
def test_the_arm_can_always_be_parked_and_homed(start: tuple[float, ...]) -> None:
    """``ArmBase.park``/``home`` walk there through the filter: from every safe pose they get
    there (joints that would dip under the floor wait while the others move)."""
    for goal in (SPEC.actuator_park_rad, SPEC.actuator_home_rad):
        f = SafetyFilter(SPEC)
        q = np.array(start)
        for _ in range(60):
            q = f.filter(goal, q)
        np.testing.assert_allclose(q, goal, atol=1e-12)


def test_move_to_a_pose_under_the_table_is_refused_at_once(
    quick_spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    """Through SerialArm and the emulator over a pty: the goal is refused with the reason before
    anything moves (rather than walking until the guard stops it and timing out), and every
    command the guard shortened still arrives above the floor."""
    emu = make_emulator(quick_spec, "s2r")
    guard = WorkspaceGuard(quick_spec)
    dive = np.array([0.0, 1.3, 0.27, 0.0])
    with SerialArm(quick_spec, emu.port, protocol="s2r", host_watchdog_s=None) as arm:
        arm.home()
        before = arm.last_sent_rad
        with pytest.raises(SafetyError, match="cannot move to .* tool at z=.* below the table"):
            arm.move_to(dive)
        np.testing.assert_array_equal(arm.last_sent_rad, before)
        sent = [arm.command(dive) for _ in range(20)]
        emu.sync()
        assert arm.safety.stats.workspace_clamped > 0
        assert max(guard.excess_m(q) for q in sent) <= ROUNDING_M
        received = [np.array(e.requested) for e in emu.applied() if e.kind == "targets"]
        assert max(guard.excess_m(arm.calibration.from_units(u)) for u in received) <= ROUNDING_M


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("margin_m: 0.008", "margin_m: -0.01", r"workspace.margin_m must be >= 0, got -0.01"),
        ("box_min_m: [-0.08, -0.3, 0.0]", "box_min_m: [-0.08, 0.0]", r"box_min_m must be 3"),
        (
            "box_min_m: [-0.08, -0.3, 0.0]",
            "box_min_m: [0.4, -0.3, 0.0]",
            r"box_min_m \[0.4, -0.3, 0.0\] must be below box_max_m",
        ),
        ("  box_min_m: [-0.08, -0.3, 0.0]", "  box_min_m: null", "given together"),
        ("table_z_m: 0.0", "table_z_m: 0.3", r"box_max_m z \(0.3\) must be above"),
        ("table_z_m: 0.0", "table_z_m: 0.09", r"the park pose .* below the table plane"),
        ("box_max_m: [0.3, 0.3, 0.3]", "box_max_m: [0.3, 0.3, 0.1]", "home pose .* outside"),
        ("margin_m: 0.008", "margin_m: 0.008\n  colour: red", r"unknown key\(s\) \['colour'\]"),
    ],
)
def test_bad_workspace_sections_fail_with_one_line(
    tmp_path: Path, old: str, new: str, message: str
) -> None:
    text = DEFAULT_SPEC_PATH.read_text()
    assert old in text
    path = tmp_path / "spec.yaml"
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(SpecError, match=message) as info:
        ArmSpec.from_yaml(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_workspace_is_safety_configuration_outside_the_fingerprint() -> None:
    """Trained policies check the fingerprint: a tighter guard, or a spec written before the
    workspace section existed, must not invalidate them."""
    tighter = replace(SPEC, workspace=replace(SPEC.workspace, margin_m=0.02))
    assert tighter.fingerprint() == SPEC.fingerprint()
    old = SPEC.to_dict()
    del old["workspace"]
    legacy = ArmSpec.from_dict(old)
    assert legacy.fingerprint() == SPEC.fingerprint()
    # no box given: the bounding box of the reach, which never cuts a pose inside the limits
    lo, hi = legacy.workspace_box_m()
    rng = np.random.default_rng(1)
    for q in rng.uniform(SPEC.lower_rad, SPEC.upper_rad, size=(500, 3)):
        for p in (SPEC.forward_kinematics(q), SPEC.elbow_position(q)):
            assert np.all(p[:2] >= lo[:2]) and np.all(p <= hi)
    # a changed behaviour field still changes it
    assert replace(SPEC, safety=replace(SPEC.safety, max_step_rad=0.2)).fingerprint() != (
        SPEC.fingerprint()
    )


# ---- the property, in-process: 10,000 cases for s2r, 2,000 each for the others ------------------
class _Pipeline:
    """Host filter + quantiser + real encoder, device-side real decoder; collects the device log."""

    def __init__(self, spec: ArmSpec, protocol: str) -> None:
        self.spec = spec
        self.protocol = protocol
        self.frame = PROTOCOLS[protocol].unit_frame(spec)
        self.cal: ArmCalibration = nominal_calibration(spec, protocol, self.frame)
        self.filter = SafetyFilter(spec)
        self.lo_u, self.hi_u = self.cal.unit_limits(spec)
        self.step_u = self.cal.max_step_units(self.filter.max_step_rad)
        self.log: list[AppliedCommand] = []
        self.t_ms = 0
        servos = ServoBank(ServoParams.from_spec(spec), spec.actuator_park_rad)
        if protocol == "s2r":
            self.core = FirmwareCore(firmware_limits(spec, self.cal), 1, on_log=self.log.append)
            self.core.feed(s2r.encode_frame(0, s2r.TORQUE, b"\x01"), 0)
        else:
            cls = FeetechDevice if protocol == "feetech" else MaestroDevice
            self.device = cls(
                spec, self.cal, servos, self.log.append, 1, 0.0, {"serial_timeout_s": 0.0}
            )
        self.seq = 0
        self.last_u = np.clip(self.cal.to_units(spec.actuator_park_rad), self.lo_u, self.hi_u)
        self.prev_rad = self.cal.from_units(self.last_u)
        if protocol != "s2r":  # bring the device's own goal to the same starting point
            self.send(self.last_u)

    def send(self, units: np.ndarray) -> None:
        self.t_ms += 50
        if self.protocol == "s2r":
            self.seq = (self.seq + 1) & 0xFF
            frame = s2r.encode_frame(self.seq, s2r.SET_TARGETS, s2r.encode_targets(units))
            self.core.feed(frame, self.t_ms)
        elif self.protocol == "feetech":
            self.device.receive(goal_packet(self.spec.actuator_ids, units), self.t_ms / 1000)
        else:
            self.device.receive(
                targets_packet(self.spec.actuator_ids, units, True), self.t_ms / 1000
            )

    def received_units(self, since: int) -> list[np.ndarray]:
        entries = [e for e in self.log[since:] if e.kind == "targets"]
        if self.protocol != "maestro":
            return [np.array(e.requested) for e in entries]
        # the Maestro logs one entry per channel: regroup by command
        n = self.spec.n_actuators
        assert len(entries) % n == 0
        return [
            np.array([e.requested[0] for e in entries[k : k + n]])
            for k in range(0, len(entries), n)
        ]


def _check_step(pipe: _Pipeline, command: tuple[float, ...]) -> None:
    """One policy output through the whole chain; what the device decoded must be safe."""
    spec = pipe.spec
    safe = pipe.filter.filter(np.array(command), pipe.prev_rad)
    units = quantise_targets(pipe.cal, safe, pipe.last_u, pipe.lo_u, pipe.hi_u, pipe.step_u)
    since = len(pipe.log)
    pipe.send(units)
    received = pipe.received_units(since)
    assert len(received) == 1
    u = received[0]
    q = pipe.cal.from_units(u)
    assert np.all(u >= pipe.lo_u) and np.all(u <= pipe.hi_u), u
    assert np.all(np.abs(u - pipe.last_u) <= pipe.step_u), (u, pipe.last_u)
    assert np.all(q >= spec.actuator_lower_rad - EPS) and np.all(
        q <= spec.actuator_upper_rad + EPS
    ), q
    assert np.all(np.abs(q - pipe.prev_rad) <= pipe.filter.max_step_rad + EPS)
    assert pipe.filter.guard.excess_m(q) <= ROUNDING_M, q  # tool and elbow in the workspace
    pipe.last_u, pipe.prev_rad = u, q


@pytest.mark.parametrize(
    ("protocol", "cases"),
    [
        pytest.param("s2r", 10_000, marks=pytest.mark.slow, id="s2r-10000"),
        pytest.param("s2r", 2_000, id="s2r-2000"),
        pytest.param("feetech", 1_000, id="feetech-1000"),
        pytest.param("maestro", 1_000, id="maestro-1000"),
    ],
)
def test_no_unsafe_command_reaches_the_device(spec: ArmSpec, protocol: str, cases: int) -> None:
    """Each case is one arbitrary policy output; the arm's state carries over from case to case,
    so every case also starts from wherever the previous ones left the arm."""
    pipe = _Pipeline(spec, protocol)

    @settings(
        max_examples=cases, deadline=None, database=None, suppress_health_check=list(HealthCheck)
    )
    @given(command=command_st)
    def prop(command: tuple[float, ...]) -> None:
        _check_step(pipe, command)

    prop()
    assert pipe.filter.stats.commands >= cases  # the property really ran that many cases
    assert (
        pipe.filter.stats.nonfinite > cases // 20 and pipe.filter.stats.limit_clamped > cases // 20
    )
    assert pipe.filter.stats.workspace_clamped > cases // 50  # the guard was really exercised


# ---- the property end to end, through a real pty ----------------------------------------------------
@pytest.mark.parametrize(("protocol", "cases"), [("s2r", 100), ("feetech", 50), ("maestro", 50)])
def test_no_unsafe_command_reaches_the_emulator_over_the_pty(
    spec: ArmSpec, make_emulator: Callable[..., Emulator], protocol: str, cases: int
) -> None:
    # judged: what reaches the device, not the timing. Hypothesis may pause between examples
    # and a loaded machine stalls: the device's watchdog and the reply time-out are relaxed.
    spec = replace(spec, safety=replace(spec.safety, watchdog_timeout_s=scaled(30.0)))
    emu = make_emulator(
        spec, protocol, EmulatorConfig(baud=1_000_000, maestro_serial_timeout_s=0.0)
    )
    with SerialArm(
        spec, emu.port, protocol=protocol, baud=1_000_000, host_watchdog_s=None,
        timeout_s=scaled(1.0),
    ) as arm:  # fmt: skip
        arm.enable()
        cal = arm.calibration
        lo, hi = spec.actuator_lower_rad, spec.actuator_upper_rad

        @settings(
            max_examples=cases,
            deadline=None,
            database=None,
            suppress_health_check=list(HealthCheck),
        )
        @given(commands=sequence_st)
        def prop(commands: list[list[float]]) -> None:
            prev = arm.last_sent_units
            since = len(emu.applied())
            sent = [arm.command(np.array(c)) for c in commands]
            emu.sync()
            entries = emu.applied()[since:]
            ids = spec.actuator_ids
            current = dict(zip(ids, prev.tolist(), strict=True))
            vectors = []
            for e in entries:
                assert e.kind == "targets"
                current.update(zip(e.ids, e.requested, strict=True))
                if e.ids[-1] == ids[-1]:
                    vectors.append(np.array([current[s] for s in ids]))
            assert len(vectors) == len(commands)
            for u, s in zip(vectors, sent, strict=True):
                q = cal.from_units(u)
                np.testing.assert_allclose(q, s, atol=1e-12)  # sent is what arrived
                assert np.all(q >= lo - EPS) and np.all(q <= hi + EPS)
                assert np.all(np.abs(u - prev) <= arm.step_units)
                assert arm.safety.guard.excess_m(q) <= ROUNDING_M, q
                prev = u

        prop()


# ---- watchdog and e-stop ------------------------------------------------------------------------
def test_watchdog_fires_once_and_kick_defers_it() -> None:
    """Kicks 20 ms apart keep a 0.5 s watchdog quiet (a stall of 0.48 s would be needed to
    break that); once they stop it fires once, never sooner than its timeout after the last."""
    timeout_s = scaled(0.5)
    fired: list[float] = []
    wd = Watchdog(timeout_s, lambda: fired.append(time.monotonic()))
    t0 = time.monotonic()
    wd.arm()
    for _ in range(10):
        time.sleep(0.02)
        last_kick = time.monotonic()
        wd.kick()
    assert not fired
    deadline = time.monotonic() + scaled(10.0)
    while not fired and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(fired) == 1 and fired[0] - last_kick >= timeout_s
    assert fired[0] - t0 >= timeout_s + 10 * 0.02  # the kicks deferred it
    wd.arm()
    wd.disarm()
    time.sleep(timeout_s + 0.1)  # past the deadline the disarmed arm() would have had
    assert len(fired) == 1
    wd.stop()
    with pytest.raises(SafetyError):
        Watchdog(0.0, lambda: None)


def test_host_watchdog_parks_a_stalled_loop_and_keeps_it_up(
    quick_spec: ArmSpec, make_emulator: Callable[..., Emulator]
) -> None:
    """The control loop stops calling command() while the host and the link live: hold, then
    park slowly with the torque on, latched (the arm does not fall)."""
    emu = make_emulator(quick_spec, "feetech")  # Feetech servos have no watchdog of their own
    with SerialArm(quick_spec, emu.port, protocol="feetech") as arm:
        arm.home()
        assert emu.torque_enabled().all()
        # then silence: the host watchdog's thread holds and parks
        assert emu.wait_until(
            lambda: arm.estop_reason is not None and "host watchdog" in arm.estop_reason,
            timeout_s=scaled(5.0),
        )
        park = quick_spec.actuator_park_rad
        assert emu.wait_until(
            lambda: bool(np.all(np.abs(emu.true_positions_rad() - park) < 0.13)),
            timeout_s=scaled(20.0),
        )
        assert emu.torque_enabled().all() and arm.is_enabled
        with pytest.raises(SafetyError, match="host watchdog"):
            arm.command(quick_spec.actuator_home_rad)
        arm.enable()  # clears the latch
        arm.command(quick_spec.actuator_home_rad)


def test_enable_during_a_fault_stop_takes_the_arm_over(
    make_emulator: Callable[..., Emulator],
) -> None:
    """A fault stop's hold runs on the watchdog's thread; an enable() from the caller (a reset
    homing the arm) ends it there: no hold or park of the old fault is sent after it, so the
    fault stop never moves an arm that someone has taken over."""
    s = load_spec()
    spec = replace(s, safety=replace(s.safety, hold_before_disable_s=scaled(30.0)))
    emu = make_emulator(spec, "feetech")
    with SerialArm(spec, emu.port, protocol="feetech") as arm:
        arm.home()
        pose = spec.actuator_home_rad.copy()
        pose[0] += 0.2
        arm.move_to(pose)
        assert emu.wait_until(  # silence: the host watchdog holds `pose` for 30 s
            lambda: arm.estop_reason is not None and "host watchdog" in arm.estop_reason,
            timeout_s=scaled(5.0),
        )
        assert emu.wait_until(lambda: len(emu.applied("targets")) > 0, timeout_s=scaled(2.0))
        held = emu.applied("targets")[-1].requested
        arm.enable()
        after = len(emu.applied("targets"))
        for _ in range(15):  # the caller's own commands, back towards home
            arm.command(spec.actuator_home_rad)
            time.sleep(0.02)
        resent = [e for e in emu.applied("targets")[after:] if e.requested == held]
        assert len(resent) <= 1, f"the fault's hold was resent {len(resent)} times"
        assert arm.estop_reason is None and arm.is_enabled


_SIGNAL_SCRIPT = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from hardware.spec import load_spec
    from hardware.serial_arm import SerialArm
    from hardware.safety import estop_on_signals
    from dataclasses import replace
    spec = load_spec()
    watchdog_s, hold_s = float(sys.argv[2]), float(sys.argv[3])
    spec = replace(spec, safety=replace(
        spec.safety, watchdog_timeout_s=watchdog_s, hold_before_disable_s=hold_s))
    with SerialArm(spec, sys.argv[1], protocol="s2r", timeout_s=watchdog_s / 2) as arm:
        arm.enable()
        with estop_on_signals(arm):
            print("ready", flush=True)
            while True:
                arm.command(spec.actuator_home_rad)
                time.sleep(0.02)
    """
)


@pytest.mark.parametrize(
    ("sig", "code"), [(signal.SIGTERM, 128 + 15), (signal.SIGINT, -signal.SIGINT)]
)
def test_signal_holds_then_disables(
    spec: ArmSpec,
    make_emulator: Callable[..., Emulator],
    spawn: Callable[..., subprocess.Popen[str]],
    sig: int,
    code: int,
) -> None:
    # the device's watchdog relaxed to 0.5 s (20 ms commands keep it fed on any machine), and
    # a hold three times as long: only the hold's re-sends keep the device from letting go
    watchdog_s = scaled(0.5)
    safety = replace(
        spec.safety, watchdog_timeout_s=watchdog_s, hold_before_disable_s=3 * watchdog_s
    )
    spec = replace(spec, safety=safety)
    emu = make_emulator(spec, "s2r")
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    proc = spawn(
        [sys.executable, "-c", _SIGNAL_SCRIPT, emu.port, str(watchdog_s), str(3 * watchdog_s)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "ready"
        time.sleep(0.2)
        assert emu.torque_enabled().all()
        t_sig = emu.now_s()
        proc.send_signal(sig)
        rc = proc.wait(timeout=scaled(30))
    finally:
        if proc.poll() is None:
            proc.kill()
    assert rc == code, proc.stderr.read() if proc.stderr else ""
    assert not emu.torque_enabled().any()
    log = emu.applied()
    off = [e for e in log if e.kind == "torque" and e.applied == (0,)]
    assert off, "torque was never switched off"
    # the firmware logs whole milliseconds: allow one
    held = [e for e in log if e.kind == "targets" and t_sig - 0.002 <= e.t_s <= off[0].t_s]
    assert held, f"no hold before the torque went off: {[(e.kind, e.t_s) for e in log[-8:]]}"
    assert off[0].t_s - held[0].t_s >= spec.safety.hold_before_disable_s - 0.02
    assert len(held) >= 5  # the hold is re-sent, so no device-side watchdog lets go early
    assert not emu.applied("watchdog_hold")
