"""The Arm contract as a library: the checks every backend passes, runnable without a test
framework (as Gymnasium ships its env checker).

A backend is an ``hardware.arm.ArmBase`` subclass. To check one, give ``check_arm`` a function
that builds a fresh, *unconnected* arm and one that builds its probe (``ArmProbe``: what the
backend really did, seen from outside the arm):

    report = check_arm(lambda: MyArm(spec), MyProbe)   # raises ContractError if a check failed
    print(report)                                      # one line per check

Each check is also a function of its own (``CHECKS`` maps their names to them), which a test
framework can run one per test against its fixtures: ``CHECKS["home"](arm, probe)``. A failure is
a ``ContractError`` (an ``AssertionError``), one line naming the check and the value:
``home: home() read [0.1 -0.3 0.9 0.] rad is not within 0.06 rad of [0. 0. 0.3 1.2]``.
The checks judge behaviour, not timing: where they wait, they wait on progress, for up to
``settle_timeout_s`` without any (a loaded machine passes a larger one).

numpy only, like the rest of ``hardware``: no test framework is imported.
"""

from __future__ import annotations

import functools
import itertools
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import FrozenInstanceError, dataclass
from typing import Any, Protocol

import numpy as np

from hardware.arm import Arm, ArmBase, ArmState
from hardware.errors import NotConnectedError, SafetyError
from hardware.spec import ArmSpec

STEP_EPS_RAD = 1e-9  # float slack on the limits and the step clamp
# Where a stopped arm may sit after a move: dead band, quantisation and lag at the end of it.
TOLERANCE_RAD = 0.06
SENT_ATOL_RAD = 1e-6  # what went out and what the backend decoded, in rad
# A wall-clock budget, never a deadline an idle machine meets and a loaded one misses: how long
# a move may go without getting closer before it counts as stuck. A busy test machine passes a
# larger one, which widens ``move_to``'s own time-out (10 s, its default) too.
SETTLE_TIMEOUT_S = 10.0
MOVE_TIMEOUT_S = 10.0
PROGRESS_RAD = 1e-4  # closer by less than this is noise, not progress
HOLD_PERIOD_S = 0.02  # the rhythm of the holds while a horn catches up (the loop's 50 Hz)


class ContractError(AssertionError):
    """A backend broke the Arm contract: ``check`` names the check, ``str()`` is one line."""

    report: ContractReport | None = None  # check_arm's, where it raised

    def __init__(self, message: str, check: str = "") -> None:
        self.check = check
        self.message = message
        super().__init__(f"{check}: {message}" if check else message)


class ArmProbe(Protocol):
    """What the backend really did, seen from outside the Arm."""

    def true_positions_rad(self) -> np.ndarray:
        """The joints' true angles (n_actuators,)."""

    def torque_enabled(self) -> bool:
        """True when every actuator is powered."""

    def received_targets_rad(self) -> list[np.ndarray]:
        """Every target vector the backend applied (as it decoded it), oldest first."""


class Check(Protocol):
    """One contract check: passes quietly or raises a ContractError naming itself."""

    def __call__(
        self,
        arm: ArmBase,
        probe: ArmProbe,
        *,
        tolerance_rad: float = ...,
        settle_timeout_s: float = ...,
    ) -> None: ...


def _v(a: Any) -> str:
    """An array on one line, rounded (messages name the value)."""
    arr = np.asarray(a, dtype=float)
    return np.array2string(arr, precision=4, suppress_small=True, max_line_width=10_000)


class _Check:
    """The assertions of one check; each failure is a ContractError naming it."""

    def __init__(self, name: str) -> None:
        self.name = name

    def fail(self, message: str) -> ContractError:
        return ContractError(message, self.name)

    def expect(self, ok: Any, message: str) -> None:
        if not ok:
            raise self.fail(message)

    def close(self, actual: Any, expected: Any, atol: float, what: str) -> None:
        a, e = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
        if a.shape != e.shape or not np.allclose(a, e, atol=atol, rtol=0.0):
            raise self.fail(f"{what} {_v(a)} rad is not within {atol:g} rad of {_v(e)}")

    def raises(
        self, kind: type[BaseException], call: Callable[[], object], what: str, match: str = ""
    ) -> None:
        """``call()`` must raise ``kind`` (with ``match`` in its message)."""
        try:
            call()
        except kind as exc:
            if match not in str(exc):
                raise self.fail(f"{what} raised {kind.__name__} without {match!r}: {exc}") from None
            return
        except Exception as exc:
            raise self.fail(
                f"{what} raised {type(exc).__name__} ({exc}), not {kind.__name__}"
            ) from None
        raise self.fail(f"{what} did not raise {kind.__name__}")

    def received_safe(self, arm: ArmBase, received: list[np.ndarray]) -> None:
        """Every target the backend applied: finite, within the limits, one clamp step apart."""
        lo, hi = arm.spec.actuator_lower_rad, arm.spec.actuator_upper_rad
        for q in received:
            self.expect(np.all(np.isfinite(q)), f"the backend applied a non-finite target {_v(q)}")
            self.expect(
                np.all(q >= lo - STEP_EPS_RAD) and np.all(q <= hi + STEP_EPS_RAD),
                f"the backend applied {_v(q)} rad, outside the limits {_v(lo)}..{_v(hi)}",
            )
        step = arm.safety.max_step_rad
        for a, b in itertools.pairwise(received):
            self.expect(
                np.all(np.abs(b - a) <= step + STEP_EPS_RAD),
                f"the backend applied {_v(a)} then {_v(b)} rad, a step over {step:g} rad",
            )


# ---- the checks -------------------------------------------------------------------------------
def check_is_an_arm(
    arm: ArmBase,
    probe: ArmProbe,
    *,
    tolerance_rad: float = TOLERANCE_RAD,
    settle_timeout_s: float = SETTLE_TIMEOUT_S,
) -> None:
    """It is an ``Arm``, and its spec counts its actuators consistently."""
    c = _Check("is_an_arm")
    c.expect(isinstance(arm, Arm), f"{type(arm).__name__} does not implement hardware.arm.Arm")
    n, names = arm.spec.n_actuators, arm.spec.actuator_names
    c.expect(n == len(names), f"spec.n_actuators is {n} but it names {len(names)}: {names}")


def check_context_manager(
    arm: ArmBase,
    probe: ArmProbe,
    *,
    tolerance_rad: float = TOLERANCE_RAD,
    settle_timeout_s: float = SETTLE_TIMEOUT_S,
) -> None:
    """``with arm as a`` connects and yields the arm; leaving releases the torque and
    disconnects (reading and commanding then raise NotConnectedError); a second close is
    harmless."""
    c = _Check("context_manager")
    with arm as a:
        c.expect(a is arm, f"__enter__ returned {a!r}, not the arm")
        state = a.read_state()
        shape = state.positions_rad.shape
        c.expect(shape == (arm.spec.n_actuators,), f"positions_rad has shape {shape}")
    c.expect(not probe.torque_enabled(), "the torque is still on after leaving the with block")
    c.raises(NotConnectedError, arm.read_state, "read_state() after close")
    home = arm.spec.actuator_home_rad
    c.raises(NotConnectedError, lambda: arm.command(home), "command() after close")
    arm.close()  # a second close is harmless


def check_state(
    arm: ArmBase,
    probe: ArmProbe,
    *,
    tolerance_rad: float = TOLERANCE_RAD,
    settle_timeout_s: float = SETTLE_TIMEOUT_S,
) -> None:
    """Readings are frozen ``ArmState``s of the right shapes, finite, read-only, with a clock
    that never runs back; at power-up they agree with the joints' true angles."""
    c = _Check("state")
    n = arm.spec.n_actuators
    with arm:
        states = [arm.read_state() for _ in range(3)]
    for s in states:
        c.expect(isinstance(s, ArmState), f"read_state() returned a {type(s).__name__}")
        c.expect(s.positions_rad.shape == (n,), f"positions_rad has shape {s.positions_rad.shape}")
        c.expect(np.all(np.isfinite(s.positions_rad)), f"positions_rad {_v(s.positions_rad)}")
        for key in ("velocities_rad_s", "loads"):
            extra = getattr(s, key)
            if extra is not None:
                c.expect(extra.shape == (n,), f"{key} has shape {extra.shape}")
        try:
            s.positions_rad[0] = 1.0
        except ValueError:
            pass
        else:
            raise c.fail("positions_rad is writable")
        try:
            s.timestamp_s = 0.0  # type: ignore[misc]
        except FrozenInstanceError:
            pass
        else:
            raise c.fail("an ArmState is not frozen: timestamp_s was set")
    stamps = [s.timestamp_s for s in states]
    c.expect(stamps == sorted(stamps), f"timestamps {stamps} run back")
    # at power-up the arm rests where it is: the reading agrees with the truth
    c.close(states[-1].positions_rad, probe.true_positions_rad(), tolerance_rad, "the reading")


def check_refused_while_torque_off(
    arm: ArmBase,
    probe: ArmProbe,
    *,
    tolerance_rad: float = TOLERANCE_RAD,
    settle_timeout_s: float = SETTLE_TIMEOUT_S,
) -> None:
    """Connected but not enabled, ``command`` raises SafetyError("torque is off") and nothing
    reaches the backend."""
    c = _Check("refused_while_torque_off")
    with arm:
        before = len(probe.received_targets_rad())
        home = arm.spec.actuator_home_rad
        c.raises(
            SafetyError, lambda: arm.command(home), "command() with torque off", "torque is off"
        )
        after = len(probe.received_targets_rad())
        c.expect(after == before, f"the backend received {after - before} targets")


def check_wrong_shape_refused(
    arm: ArmBase,
    probe: ArmProbe,
    *,
    tolerance_rad: float = TOLERANCE_RAD,
    settle_timeout_s: float = SETTLE_TIMEOUT_S,
) -> None:
    """A target of the wrong shape or type raises SafetyError."""
    c = _Check("wrong_shape_refused")
    with arm:
        arm.enable()
        bad_targets: tuple[object, ...] = ([0.0, 0.0], np.zeros((2, 2)), "home", None)
        for bad in bad_targets:
            c.raises(SafetyError, functools.partial(arm.command, bad), f"command({bad!r})")


def check_sent_is_received(
    arm: ArmBase,
    probe: ArmProbe,
    *,
    tolerance_rad: float = TOLERANCE_RAD,
    settle_timeout_s: float = SETTLE_TIMEOUT_S,
) -> None:
    """What ``command`` returns as sent is what the backend applied."""
    c = _Check("sent_is_received")
    with arm:
        arm.enable()
        goal = arm.spec.actuator_home_rad
        for _ in range(3):
            sent = arm.command(goal)
            c.expect(
                sent.shape == (arm.spec.n_actuators,), f"command() returned shape {sent.shape}"
            )
            received = probe.received_targets_rad()
            c.expect(received, "the backend logged no targets")
            c.close(received[-1], sent, SENT_ATOL_RAD, "the backend applied")


def check_limits_step_nonfinite(
    arm: ArmBase,
    probe: ArmProbe,
    *,
    tolerance_rad: float = TOLERANCE_RAD,
    settle_timeout_s: float = SETTLE_TIMEOUT_S,
) -> None:
    """Huge, infinite and NaN targets: what goes out stays within the limits and one clamp step
    of the last, a non-finite entry holds its actuator, and the backend applied only such."""
    c = _Check("limits_step_nonfinite")
    spec = arm.spec
    lo, hi = spec.actuator_lower_rad, spec.actuator_upper_rad
    step = arm.safety.max_step_rad
    with arm:
        arm.enable()
        first = len(probe.received_targets_rad())
        prev = arm.last_sent_rad
        c.expect(prev is not None, "last_sent_rad is None after enable()")
        assert prev is not None
        nasty = [
            np.full(spec.n_actuators, 1e9),
            np.full(spec.n_actuators, -np.inf),
            np.full(spec.n_actuators, np.nan),
            np.resize(np.array([np.nan, np.inf, -1e9, 0.3]), spec.n_actuators),
            hi + 10.0,
        ]
        for target in nasty:
            sent = arm.command(target)
            asked = f"command({_v(target)}) sent {_v(sent)} rad"
            c.expect(
                np.all(sent >= lo - STEP_EPS_RAD) and np.all(sent <= hi + STEP_EPS_RAD),
                f"{asked}, outside the limits {_v(lo)}..{_v(hi)}",
            )
            c.expect(
                np.all(np.abs(sent - prev) <= step + STEP_EPS_RAD),
                f"{asked}, more than {step:g} rad from the last {_v(prev)}",
            )
            nonfinite = ~np.isfinite(target)
            c.close(sent[nonfinite], prev[nonfinite], 1e-9, f"{asked}: the non-finite entries")
            prev = sent
        received = probe.received_targets_rad()[first:]
        c.expect(
            len(received) >= len(nasty),
            f"the backend received {len(received)} targets for {len(nasty)} commands",
        )
        c.received_safe(arm, received)


def check_moves_to_a_pose(
    arm: ArmBase,
    probe: ArmProbe,
    *,
    tolerance_rad: float = TOLERANCE_RAD,
    settle_timeout_s: float = SETTLE_TIMEOUT_S,
) -> None:
    """``move_to`` a pose near home: the reading arrives, the joints truly get there while the
    arm is held, and every target on the way was safe."""
    c = _Check("moves_to_a_pose")
    spec = arm.spec
    goal = np.clip(spec.actuator_home_rad + 0.2, spec.actuator_lower_rad, spec.actuator_upper_rad)
    with arm:
        state = arm.move_to(
            goal, tolerance_rad=tolerance_rad, timeout_s=max(MOVE_TIMEOUT_S, settle_timeout_s)
        )
        c.close(state.positions_rad, goal, tolerance_rad, "move_to() returned a reading")
        _hold_until_there(arm, probe, goal, tolerance_rad, settle_timeout_s)
        c.close(probe.true_positions_rad(), goal, tolerance_rad, "the true position")
        c.received_safe(arm, probe.received_targets_rad())


def _hold_until_there(
    arm: ArmBase, probe: ArmProbe, goal: np.ndarray, tolerance_rad: float, settle_timeout_s: float
) -> None:
    """Servos without feedback report the commanded pulse: the horn may still be on its way.
    Hold while it gets closer; stop once there, or after ``settle_timeout_s`` without progress
    (a loaded machine makes a move slow, not stuck, so a count of holds would misjudge it)."""
    best_rad = np.inf
    last_progress_s = time.monotonic()
    while True:
        error_rad = float(np.max(np.abs(probe.true_positions_rad() - goal)))
        if error_rad <= tolerance_rad:
            return
        now_s = time.monotonic()
        if error_rad < best_rad - PROGRESS_RAD:
            best_rad, last_progress_s = error_rad, now_s
        elif now_s - last_progress_s > settle_timeout_s:
            return  # stuck: the caller's check names how far off it stayed
        arm.hold()
        time.sleep(HOLD_PERIOD_S)


def check_home(
    arm: ArmBase,
    probe: ArmProbe,
    *,
    tolerance_rad: float = TOLERANCE_RAD,
    settle_timeout_s: float = SETTLE_TIMEOUT_S,
) -> None:
    """``home()`` switches the torque on and arrives at the spec's home pose."""
    c = _Check("home")
    with arm:
        state = arm.home()
        c.expect(probe.torque_enabled(), "the torque is off after home()")
        c.close(state.positions_rad, arm.spec.actuator_home_rad, tolerance_rad, "home() read")


def check_disable_and_close_release_torque(
    arm: ArmBase,
    probe: ArmProbe,
    *,
    tolerance_rad: float = TOLERANCE_RAD,
    settle_timeout_s: float = SETTLE_TIMEOUT_S,
) -> None:
    """``disable()`` releases the torque and refuses commands until ``enable()``; leaving the
    with block releases it too."""
    c = _Check("disable_and_close_release_torque")
    home = arm.spec.actuator_home_rad
    with arm:
        arm.enable()
        c.expect(probe.torque_enabled(), "the torque is off after enable()")
        arm.disable()
        c.expect(not probe.torque_enabled(), "the torque is on after disable()")
        c.raises(SafetyError, lambda: arm.command(home), "command() after disable()")
        arm.enable()
        arm.command(home)
        c.expect(probe.torque_enabled(), "the torque is off after enable() and command()")
    c.expect(not probe.torque_enabled(), "the torque is on after close()")


def check_operator_estop_survives_home(
    arm: ArmBase,
    probe: ArmProbe,
    *,
    tolerance_rad: float = TOLERANCE_RAD,
    settle_timeout_s: float = SETTLE_TIMEOUT_S,
) -> None:
    """After a fault's e-stop, ``home()`` re-enables (a simulated arm recovers for the next
    episode); after a person's, only an explicit ``enable()`` moves the arm again."""
    c = _Check("operator_estop_survives_home")
    with arm:
        arm.home()
        arm.estop("a fault")
        arm.home()
        c.expect(probe.torque_enabled(), "the torque is off after a fault's e-stop and home()")
        c.expect(arm.estop_reason is None, f"estop_reason is {arm.estop_reason!r} after home()")
        arm.estop("the e-stop key", operator=True)
        c.raises(SafetyError, arm.home, "home() after an operator's e-stop", "e-stop latched")
        c.expect(not probe.torque_enabled(), "the torque is on after an operator's e-stop")
        arm.enable()
        arm.home()
        c.expect(probe.torque_enabled(), "the torque is off after enable() and home()")


def check_estop_holds_then_releases(
    arm: ArmBase,
    probe: ArmProbe,
    *,
    tolerance_rad: float = TOLERANCE_RAD,
    settle_timeout_s: float = SETTLE_TIMEOUT_S,
) -> None:
    """``estop()`` sends the last targets again (the hold), then releases the torque; the latch
    refuses commands until ``enable()``."""
    c = _Check("estop_holds_then_releases")
    home = arm.spec.actuator_home_rad
    with arm:
        arm.enable()
        sent = arm.command(home)
        n_before = len(probe.received_targets_rad())
        arm.estop("contract check")
        received = probe.received_targets_rad()
        c.expect(len(received) > n_before, "the e-stop sent no hold (no targets after it)")
        c.close(received[-1], sent, SENT_ATOL_RAD, "the e-stop held")
        c.expect(not probe.torque_enabled(), "the torque is on after estop()")
        c.raises(SafetyError, lambda: arm.command(home), "command() after estop()", "e-stop")
        arm.enable()
        arm.command(home)
        c.expect(probe.torque_enabled(), "the torque is off after enable() and command()")


CHECKS: Mapping[str, Check] = {
    "is_an_arm": check_is_an_arm,
    "context_manager": check_context_manager,
    "state": check_state,
    "refused_while_torque_off": check_refused_while_torque_off,
    "wrong_shape_refused": check_wrong_shape_refused,
    "sent_is_received": check_sent_is_received,
    "limits_step_nonfinite": check_limits_step_nonfinite,
    "moves_to_a_pose": check_moves_to_a_pose,
    "home": check_home,
    "disable_and_close_release_torque": check_disable_and_close_release_torque,
    "operator_estop_survives_home": check_operator_estop_survives_home,
    "estop_holds_then_releases": check_estop_holds_then_releases,
}


# ---- the entry point --------------------------------------------------------------------------
@dataclass(frozen=True)
class CheckResult:
    name: str
    error: str | None  # one line; None: passed
    wall_s: float

    @property
    def passed(self) -> bool:
        return self.error is None


@dataclass(frozen=True)
class ContractReport:
    """Each check's outcome, in the order run."""

    backend: str
    results: tuple[CheckResult, ...]

    @property
    def failed(self) -> tuple[CheckResult, ...]:
        return tuple(r for r in self.results if not r.passed)

    @property
    def ok(self) -> bool:
        return not self.failed

    def __str__(self) -> str:
        lines = [
            f"{self.backend}: {len(self.results) - len(self.failed)}/{len(self.results)} "
            "contract checks passed"
        ]
        for r in self.results:
            lines.append(f"  {'ok  ' if r.passed else 'FAIL'} {r.name} ({r.wall_s:.2f} s)")
            if r.error is not None:
                lines.append(f"       {r.error}")
        return "\n".join(lines)


def _spec_problem(arm: ArmBase, spec: ArmSpec) -> str:
    if arm.spec.actuator_names != spec.actuator_names:
        return f"the arm drives {arm.spec.actuator_names}, the spec {spec.actuator_names}"
    if arm.spec.fingerprint() != spec.fingerprint():
        return (
            f"the arm's spec {arm.spec.name!r} ({arm.spec.fingerprint()}) is not "
            f"{spec.name!r} ({spec.fingerprint()})"
        )
    return ""


def check_arm(
    make_arm: Callable[[], ArmBase],
    make_probe: Callable[[ArmBase], ArmProbe],
    spec: ArmSpec | None = None,
    *,
    tolerance_rad: float = TOLERANCE_RAD,
    settle_timeout_s: float = SETTLE_TIMEOUT_S,
    only: Iterable[str] | None = None,
    raise_on_failure: bool = True,
) -> ContractReport:
    """Run the contract checks (``only`` those named, default all), each on a fresh unconnected
    arm from ``make_arm`` and its probe from ``make_probe(arm)``; each arm is closed after its
    check. ``spec``, where given, is the spec every arm must carry. ``tolerance_rad``: where a
    stopped arm may sit; ``settle_timeout_s``: how long a move may go without getting closer
    (wall clock: a loaded machine passes more). Returns the report; raises
    ``ContractError`` naming every failed check (after running them all) unless
    ``raise_on_failure`` is False. An exception other than a ContractError in a check (a
    backend error) fails that check with the exception's line; KeyboardInterrupt stops all."""
    names = list(CHECKS) if only is None else list(only)
    unknown = [n for n in names if n not in CHECKS]
    if unknown:
        raise ValueError(f"unknown contract checks {unknown}; known: {', '.join(CHECKS)}")
    backend = ""
    results: list[CheckResult] = []
    for name in names:
        t0 = time.monotonic()
        error: str | None = None
        arm = make_arm()
        backend = backend or type(arm).__name__
        try:
            why = "" if spec is None else _spec_problem(arm, spec)
            if why:
                raise ContractError(why, "spec")
            CHECKS[name](
                arm, make_probe(arm), tolerance_rad=tolerance_rad, settle_timeout_s=settle_timeout_s
            )
        except ContractError as exc:
            error = str(exc)
        except Exception as exc:
            error = f"{name}: {type(exc).__name__}: {exc}".splitlines()[0]
        finally:
            arm.close()
        results.append(CheckResult(name, error, round(time.monotonic() - t0, 3)))
    report = ContractReport(backend or "arm", tuple(results))
    if raise_on_failure and not report.ok:
        failed = "; ".join(r.error or r.name for r in report.failed)
        err = ContractError(f"{len(report.failed)} of {len(results)} failed: {failed}", "check_arm")
        err.report = report
        raise err
    return report
