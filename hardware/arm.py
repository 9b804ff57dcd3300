"""The Arm interface every backend implements, and the base class that puts safety in front.

``ArmBase`` does the bookkeeping once (connection state, the safety filter, the host watchdog,
e-stop, torque-off on close) and calls a handful of protected hooks that a backend implements:
``_connect``, ``_close``, ``_read_state``, ``_send_targets``, ``_set_torque``. The serial backend
(``SerialArm``) and the MuJoCo backend (``SimArm``) both derive from it, so neither can skip the
safety layer, and one contract suite (``hardware.testing``) checks every backend.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Protocol, TypeVar, runtime_checkable

import numpy as np

from hardware.errors import (
    DeviceResetError,
    HardwareError,
    NotConnectedError,
    SafetyError,
    StallError,
    TorqueOffError,
)
from hardware.safety import SafetyFilter, Watchdog
from hardware.servo_model import arrival_time_s
from hardware.spec import ArmSpec

log = logging.getLogger(__name__)

_A = TypeVar("_A", bound="ArmBase")
_SPEC_DEFAULT = -1.0  # sentinel: take the host watchdog timeout from the spec
_HOLD_RESEND_S = 0.05  # during an e-stop hold, resend the targets this often
_KEEP_S = 0.1  # after a fault stop, resend the held pose this often (device watchdogs: 250 ms)


def _frozen(a: np.ndarray | None) -> np.ndarray | None:
    if a is None:
        return None
    out = np.array(a, dtype=float, copy=True)
    out.setflags(write=False)
    return out


def arrival_tolerance_rad(spec: ArmSpec) -> float:
    """Where an arrived servo may sit: inside its dead band, plus one quantisation step of the
    command and one of the reading. From the spec's servo figures (fitted ones after sysid)."""
    return spec.servo.deadband_rad + 2.0 * spec.servo.resolution_rad


def off_pose_limit_rad(spec: ArmSpec) -> float:
    """How far short of a pose a stopped arm may be and still be used (with a warning): half a
    safe step, so the first command from there is still an ordinary step of the safety clamp."""
    return 0.5 * spec.safety.max_step_rad


def settle_window_s(spec: ArmSpec) -> float:
    """How long without progress means "stopped": five servo time constants after the servo's
    latency (99 % of a first-order step), and never less than a quarter second."""
    return max(0.25, spec.servo.latency_s + 5.0 * spec.servo.time_constant_s)


def stall_error_rad(spec: ArmSpec) -> float:
    """The tracking error a stopped joint may keep without being stalled: the bound ``move_to``
    accepts as "off the pose but usable" (droop and a worn dead band stay under it)."""
    return off_pose_limit_rad(spec)


def stall_window_s(spec: ArmSpec) -> float:
    """How long a healthy servo may sit still with an error beyond ``stall_error_rad``: its
    latency and three time constants (95 % of a first-order response; the first tenth of it
    comes within a fraction of one)."""
    return spec.servo.latency_s + 3.0 * spec.servo.time_constant_s


def park_speed_rad_s(spec: ArmSpec) -> float:
    """How fast a fault stop parks the arm: a fifth of the servo's speed, slow enough to watch
    and to stop by hand."""
    return 0.2 * spec.servo.max_speed_rad_s


class _FaultSupersededError(Exception):
    """A fault stop's hold or park found the arm re-enabled, disabled or e-stopped by another
    thread since it began: that caller now owns the arm, so the fault stop ends where it is."""


@dataclass(frozen=True)
class ArmState:
    """One reading of the arm, in ``spec.actuator_names`` order (joints, then gripper)."""

    positions_rad: np.ndarray  # (n_actuators,)
    timestamp_s: float  # time.monotonic() of the reading (sim time for SimArm)
    velocities_rad_s: np.ndarray | None = None  # (n_actuators,) where the servos report it
    loads: np.ndarray | None = None  # (n_actuators,) signed fraction of max torque, if reported
    # (n_actuators,) bool: True where the position was measured on the horn, False where it is
    # the command the servo was sent (a bare PWM servo). None: every position is measured (a
    # backend that reads the joint itself, as SimArm reads MuJoCo). The serial backend always
    # says which, from the wire.
    measured: np.ndarray | None = None

    def __post_init__(self) -> None:
        pos = _frozen(self.positions_rad)
        assert pos is not None
        if pos.ndim != 1:
            raise ValueError(f"positions_rad must be 1-D, got shape {pos.shape}")
        object.__setattr__(self, "positions_rad", pos)
        for key in ("velocities_rad_s", "loads"):
            value = _frozen(getattr(self, key))
            if value is not None and value.shape != pos.shape:
                raise ValueError(f"{key} must have shape {pos.shape}, got {value.shape}")
            object.__setattr__(self, key, value)
        if self.measured is not None:
            m = np.array(self.measured, dtype=bool, copy=True)
            if m.shape != pos.shape:
                raise ValueError(f"measured must have shape {pos.shape}, got {m.shape}")
            m.setflags(write=False)
            object.__setattr__(self, "measured", m)

    @property
    def measured_mask(self) -> np.ndarray:
        """(n_actuators,) bool: which positions were measured (all, where None)."""
        if self.measured is None:
            return np.ones(self.positions_rad.shape, dtype=bool)
        return self.measured


class StallMonitor:
    """Stall detection from what can be felt: a measured joint whose reading stays further than
    ``stall_error_rad`` from its command without moving by ``stall_progress_rad`` for
    ``stall_window_s`` has stalled (jammed, blocked, a stripped gear). A healthy servo starts
    closing such an error within its latency and a fraction of its time constant, a slow one
    still moves, and droop stays under the bound. Joints that read their command are skipped:
    their reading cannot disagree with the command. The gripper is skipped too: squeezing a cube
    is its job (the grasp signal reads that very stall)."""

    def __init__(self, spec: ArmSpec) -> None:
        self.error_rad = stall_error_rad(spec)
        self.progress_rad = 2.0 * arrival_tolerance_rad(spec)  # pot noise and a count or two
        self.window_s = stall_window_s(spec)
        self.names = spec.actuator_names
        self.watched = np.arange(spec.n_actuators) < spec.n_joints  # (n,) joints, not gripper
        self.reset()

    def reset(self) -> None:
        self._anchor_rad: np.ndarray | None = None  # where each joint was when its error rose
        self._anchor_s = np.zeros(len(self.names))
        self._off = np.zeros(len(self.names), dtype=bool)

    def update(self, state: ArmState, sent_rad: np.ndarray | None) -> tuple[np.ndarray, str]:
        """(stalled (n,) bool, a one-line reason naming the joint, or "")."""
        pos, t = state.positions_rad, state.timestamp_s
        none = np.zeros(pos.shape, dtype=bool)
        if sent_rad is None:
            return none, ""
        if self._anchor_rad is None:
            self._anchor_rad = pos.copy()
        err = np.abs(pos - sent_rad)
        off = (err > self.error_rad) & state.measured_mask & self.watched
        moved = np.abs(pos - self._anchor_rad) > self.progress_rad
        restart = off & (~self._off | moved)  # the error just rose, or the joint moved
        self._anchor_rad = np.where(restart | ~off, pos, self._anchor_rad)
        self._anchor_s = np.where(restart | ~off, t, self._anchor_s)
        self._off = off
        stalled = off & (t - self._anchor_s >= self.window_s)
        if not stalled.any():
            return none, ""
        j = int(np.argmax(np.where(stalled, err, -1.0)))
        return stalled, (
            f"stall: {self.names[j]} is {err[j]:.3f} rad from its command and has not moved for "
            f"{t - self._anchor_s[j]:.2f} s (a healthy servo answers within {self.window_s:.2f} "
            f"s; allowed error {self.error_rad:.3f} rad)"
        )


@runtime_checkable
class Arm(Protocol):
    """What the deploy loop, the CLI and the contract tests rely on."""

    spec: ArmSpec

    def connect(self) -> None: ...

    def close(self) -> None: ...

    def __enter__(self) -> Arm: ...

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None: ...

    def read_state(self) -> ArmState: ...

    def command(self, targets_rad: Any) -> np.ndarray: ...

    def enable(self) -> None: ...

    def disable(self) -> None: ...

    def home(self) -> ArmState: ...


class ArmBase(ABC):
    """Safety, watchdog and lifecycle for every backend; subclasses implement the hooks."""

    def __init__(
        self,
        spec: ArmSpec,
        *,
        max_step_rad: float | None = None,
        on_nonfinite: str = "hold",
        host_watchdog_s: float | None = _SPEC_DEFAULT,
    ) -> None:
        self.spec = spec
        self.safety = SafetyFilter(spec, max_step_rad=max_step_rad, on_nonfinite=on_nonfinite)
        self._lock = threading.RLock()
        self._connected = False
        self._enabled = False
        self._estop_reason: str | None = None
        self._estop_by_operator = False  # a person's e-stop: only enable() clears it
        self._last_sent: np.ndarray | None = None
        self._stall = StallMonitor(spec)
        self._in_fault = False  # a fault stop is running: no nested one, no stall checks
        self._keeper_token = 0  # bumped to end the thread that holds the arm after a fault
        # the keeper token a running fault stop started under: enable(), disable(), estop() or
        # close() from another thread bump the token, and the fault's hold and park then end
        # there instead of moving an arm that someone else has taken over
        self._fault_token: int | None = None
        self._said_unfelt = False
        self._said_unwatched = False
        # (time.monotonic() of the reading that showed it, one-line reason) of the last fault
        self.last_fault: tuple[float, str] | None = None
        timeout = (
            spec.safety.watchdog_timeout_s if host_watchdog_s == _SPEC_DEFAULT else host_watchdog_s
        )
        # None switches the host watchdog off: only for backends without hardware (SimArm
        # stepping faster than real time); the device-side watchdog still runs on real arms.
        self._watchdog = (
            Watchdog(timeout, self._on_watchdog, name=f"{type(self).__name__}-watchdog")
            if timeout is not None
            else None
        )

    # ---- hooks ----------------------------------------------------------------------------
    @abstractmethod
    def _connect(self) -> None:
        """Open the transport and check the device is there."""

    @abstractmethod
    def _close(self) -> None:
        """Release the transport (torque is already off)."""

    @abstractmethod
    def _read_state(self) -> ArmState:
        """One reading."""

    @abstractmethod
    def _send_targets(self, targets_rad: np.ndarray) -> np.ndarray:
        """Send safe targets; return exactly what went out (after quantisation), in rad."""

    @abstractmethod
    def _set_torque(self, on: bool, hold_rad: np.ndarray | None) -> None:
        """Torque on holding ``hold_rad``, or off."""

    def _reference(self, state: ArmState) -> np.ndarray:
        """The targets the device holds right now (the per-step clamp starts from here)."""
        return self.safety.clip_to_limits(state.positions_rad)

    # ---- time -------------------------------------------------------------------------------
    @property
    def lockstep_period_s(self) -> float | None:
        """The time one command advances this arm's world where that time moves only with
        commands (a lockstep simulator: the world waits for the host, so nothing need sleep
        between commands, and a slow host changes no outcome); None where the arm moves with
        the wall clock, as every real arm does."""
        return None

    def now_s(self) -> float:
        """The arm's clock: ``time.monotonic()``, or a lockstep simulator's own time."""
        return time.monotonic()

    # ---- lifecycle ------------------------------------------------------------------------
    @property
    def is_connected(self) -> bool:
        return self._connected

    @property
    def is_enabled(self) -> bool:
        return self._enabled

    @property
    def last_sent_rad(self) -> np.ndarray | None:
        return None if self._last_sent is None else self._last_sent.copy()

    @property
    def estop_reason(self) -> str | None:
        return self._estop_reason

    def connect(self) -> None:
        with self._lock:
            if self._connected:
                return
            self._connect()
            try:
                state = self._read_state()
                self._last_sent = self._reference(state)
            except BaseException:
                self._close()
                raise
            self._connected = True
            self._enabled = False
            self._estop_reason = None

    def close(self) -> None:
        """Torque off, then release the port. Safe to call twice."""
        with self._lock:
            if not self._connected:
                return
            self._keeper_token += 1
            if self._watchdog is not None:
                self._watchdog.disarm()
            try:
                self._set_torque(False, None)
            except HardwareError as exc:
                log.warning("torque-off on close failed: %s", exc)
            finally:
                self._enabled = False
                self._connected = False
                self._close()
        if self._watchdog is not None:
            self._watchdog.stop()

    def __enter__(self: _A) -> _A:
        self.connect()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def _require_connected(self) -> None:
        if not self._connected:
            raise NotConnectedError(
                f"{type(self).__name__} is not connected: call connect() or use it in a with block"
            )

    # ---- operations -----------------------------------------------------------------------
    def read_state(self) -> ArmState:
        """One reading. While enabled, measured joints are watched for stalls: one that stopped
        following its command is held, the arm parked slowly, and StallError raised. A device
        that rebooted (brown-out) while the link is alive is switched back on where it is (or
        was last sent), held and parked, and the DeviceResetError raised."""
        why = ""
        stalled: np.ndarray | None = None
        with self._lock:
            self._require_connected()
            was_on = self._enabled and self._estop_reason is None
            try:
                state = self._read_state()
            except DeviceResetError as exc:
                reset: DeviceResetError | None = exc
            else:
                reset = None
                if self._enabled and self._estop_reason is None and not self._in_fault:
                    stalled, why = self._stall.update(state, self._last_sent)
        # the stop runs outside the lock, step by step, so an operator's e-stop cuts in
        if reset is not None:
            raise DeviceResetError(self._after_reset(reset, was_on)) from None
        if why:
            self.last_fault = (state.timestamp_s, why)
            raise StallError(self._fault_stop(why, held=stalled, state=state))
        return state

    def command(self, targets_rad: Any) -> np.ndarray:
        """Filter ``targets_rad`` through safety, send it, return what actually went out."""
        with self._lock:
            self._require_connected()
            if self._estop_reason is not None:
                if self._enabled:
                    raise SafetyError(
                        f"stopped after a fault ({self._estop_reason}), holding; call enable() "
                        "to resume"
                    )
                raise SafetyError(f"e-stop latched ({self._estop_reason}); call enable() to resume")
            if not self._enabled:
                raise TorqueOffError("torque is off: call enable() (or home()) before command()")
            try:
                sent = self._filtered_send(targets_rad)
            except DeviceResetError as exc:  # it was enabled: command() checked
                reset = exc
            else:
                if self._watchdog is not None:
                    self._watchdog.kick()
                return sent
        raise DeviceResetError(self._after_reset(reset, True)) from None

    def _filtered_send(self, targets_rad: Any) -> np.ndarray:
        """Safety filter, send, remember (lock held; no latch check: the fault stop uses it)."""
        assert self._last_sent is not None
        safe = self.safety.filter(targets_rad, self._last_sent)
        sent = np.asarray(self._send_targets(safe), dtype=float)
        self._last_sent = sent.copy()
        return sent

    def hold(self) -> np.ndarray:
        """Resend the last targets: keeps every watchdog fed without moving (jog, prompts)."""
        with self._lock:
            assert self._last_sent is not None or not self._connected
            return self.command(self._last_sent)

    def enable(self) -> None:
        """Torque on at the pose the device holds now (a measured servo where it is, one that
        reads its command where this host last sent it: no snap); clears a latched e-stop."""
        with self._lock:
            self._require_connected()
            self._keeper_token += 1
            self._before_enable()
            state = self._read_state()
            self._set_torque(True, self._reference(state))
            state = self._read_state()
            self._last_sent = self._reference(state)
            self._say_unwatched(state)
            self._enabled = True
            self._estop_reason = None
            self._estop_by_operator = False
            self._stall.reset()
            if self._watchdog is not None:
                self._watchdog.arm()

    def _before_enable(self) -> None:  # noqa: B027 - an optional hook, empty by default
        """Hook: re-synchronise after a device reset (SerialArm)."""

    def disable(self) -> None:
        with self._lock:
            self._require_connected()
            self._keeper_token += 1
            if self._watchdog is not None:
                self._watchdog.disarm()
            self._set_torque(False, None)
            self._enabled = False

    def move_to(
        self,
        target_rad: np.ndarray,
        *,
        tolerance_rad: float | None = None,
        timeout_s: float = 10.0,
        rate_hz: float = 50.0,
        max_speed_rad_s: float | None = None,
        judged: np.ndarray | None = None,
    ) -> ArmState:
        """Walk to ``target_rad`` through the per-step clamp at ``rate_hz`` (and no faster than
        ``max_speed_rad_s`` where given); return the state once every actuator has arrived. A
        lockstep simulator (``lockstep_period_s``) takes one command per its period instead,
        unslept, and the walk's times are its own.
        ``judged`` (a boolean mask over the actuators, default all) leaves some out of the
        arrival check: a gripper closed on an object is commanded shut and stops at the object,
        by design.

        A measured actuator has arrived when it reads within ``tolerance_rad`` (default:
        ``arrival_tolerance_rad(spec)``, from the servo figures, which sysid's fitted spec
        carries). One that reads its own command cannot be seen arriving: it has arrived when
        its reading is there and the servo model's time for the move has passed (from the
        first command, and from the last one that moved it: a host running late sends late),
        which is logged. An arm that stops short (droop, a wider dead band than the spec says)
        but within ``off_pose_limit_rad(spec)`` is warned about and returned: it works, a
        little off. One that stops further away, is still away at ``timeout_s``, or stalls, is
        held and parked slowly (``HardwareError``/``StallError`` say how it ended; torque goes
        off only where the arm could not move)."""
        target = self.safety.clip_to_limits(self.safety.check_shape(target_rad))
        outside = self.spec.workspace_violation(target[: self.spec.n_joints])
        if outside:  # the guard would hold it short: say so now, not after the timeout
            raise SafetyError(f"cannot move to {np.round(target, 3).tolist()} rad: {outside}")
        if self._estop_reason is not None and self._estop_by_operator:
            raise SafetyError(
                f"e-stop latched ({self._estop_reason}); a person must call enable() to resume"
            )
        if not self._enabled or self._estop_reason is not None:
            self.enable()
        mask = np.ones(self.spec.n_actuators, bool) if judged is None else np.asarray(judged, bool)
        if mask.shape != (self.spec.n_actuators,) or not mask.any():
            raise SafetyError(
                f"judged must mark some of the {self.spec.n_actuators} actuators, got {judged!r}"
            )
        tol = arrival_tolerance_rad(self.spec) if tolerance_rad is None else float(tolerance_rad)
        state, failure = self._walk(target, tol, timeout_s, rate_hz, max_speed_rad_s, judged=mask)
        if failure:
            raise HardwareError(self._fault_stop(failure))
        assert state is not None
        return state

    def _walk(
        self,
        target: np.ndarray,
        tol: float,
        timeout_s: float,
        rate_hz: float,
        max_speed_rad_s: float | None,
        held: np.ndarray | None = None,
        fault: bool = False,
        judged: np.ndarray | None = None,
    ) -> tuple[ArmState | None, str]:
        """The loop of ``move_to``: (state, "") once arrived, or (None, why not). ``held`` (n,)
        bool: actuators that keep their last target (a stalled joint). ``fault``: the park of
        a fault stop, which moves although the latch refuses everyone else's commands. The lock
        is taken per step, so an e-stop from another thread ends the walk at the next one."""
        spec = self.spec
        off_pose = max(off_pose_limit_rad(spec), tol)
        window_s = settle_window_s(spec)
        progress_rad = spec.servo.resolution_rad + 0.25 * tol  # less is noise, not motion
        period = 1.0 / rate_hz
        held_mask = np.zeros(spec.n_actuators, bool) if held is None else np.asarray(held, bool)
        judged_mask = np.ones(spec.n_actuators, bool) if judged is None else np.asarray(judged)
        assert self._last_sent is not None
        hold_at = self._last_sent.copy()
        start_state = self._walk_read(fault)
        felt = start_state.measured_mask | held_mask
        model_s = arrival_time_s(
            spec, start_state.positions_rad, target, tol, command_speed_rad_s=max_speed_rad_s
        )
        # a lockstep world: each command advances it one of its periods, judged on its clock
        lockstep_s = self.lockstep_period_s
        if lockstep_s is not None:
            period = lockstep_s
        start = self.now_s()
        deadline = start + timeout_s
        next_t = start
        prev_sent: np.ndarray | None = None
        # per actuator: when the last command that moved it went out, and where it was sent
        # before that; the model's time from there is what its horn still needs (a host that
        # ran late sent its steps late, and the horn that follows them arrives late too)
        changed_at = np.full(spec.n_actuators, start)
        before_change = start_state.positions_rad.copy()
        tail_s: np.ndarray | None = None
        best = np.full(spec.n_actuators, np.inf)
        last_progress_t = start
        while True:
            goal = np.where(held_mask, hold_at, target)
            sent_at = self.now_s()
            if not fault:
                sent = self.command(self._ramp(goal, max_speed_rad_s, period))
            else:
                with self._lock:
                    self._check_fault_owner()
                    if not (self._connected and self._enabled) or self._estop_by_operator:
                        raise SafetyError("the park was interrupted (torque off or an e-stop)")
                    sent = self._filtered_send(self._ramp(goal, max_speed_rad_s, period))
            state = self._walk_read(fault)
            now = self.now_s()
            err = np.where(held_mask | ~judged_mask, 0.0, np.abs(state.positions_rad - target))
            worst = int(np.argmax(err))
            name = spec.actuator_names[worst]
            # the targets sit on the goal once the step clamp no longer moves them
            settled_targets = prev_sent is not None and np.array_equal(sent, prev_sent)
            if not settled_targets:
                best[:] = np.inf
                last_progress_t = now
                if prev_sent is not None:
                    moved = sent != prev_sent
                    changed_at = np.where(moved, sent_at, changed_at)
                    before_change = np.where(moved, prev_sent, before_change)
                    tail_s = None
                prev_sent = sent
            else:
                if tail_s is None:
                    tail_s = np.zeros(spec.n_actuators)
                    if np.any(~felt):  # only a joint that reads its command waits for it
                        tail_s = arrival_time_s(
                            spec, before_change, target, tol, command_speed_rad_s=max_speed_rad_s
                        )
                waited = (now - start >= model_s) & (now - changed_at >= tail_s)
                if np.all((err <= tol) & (felt | waited)):
                    self._say_unfelt(~felt, np.maximum(model_s, changed_at - start + tail_s))
                    return state, ""
                improved = err < best - progress_rad  # against the last progress, so a slow
                if np.any(improved & felt):  # but moving arm adds up to progress in the window
                    last_progress_t = now
                best = np.where(improved, err, best)
                # all within the tolerance: only the unfelt joints' model time is left to wait,
                # nothing stopped short of the pose
                short = not np.all(err <= tol)
                if short and now - last_progress_t >= window_s and np.all(err[~felt] <= tol):
                    if np.all(err <= off_pose):  # stopped moving, short of the pose
                        log.warning(
                            "settled %.3f rad off the pose at %s (arrival tolerance %.4f rad): "
                            "droop or a dead band the spec does not describe; `sim2real sysid` "
                            "fits them",
                            err[worst],
                            name,
                            tol,
                        )
                        return state, ""
                    return None, (
                        f"did not reach the pose: {name} stopped {err[worst]:.3f} rad away "
                        f"(arrival tolerance {tol:.4f} rad, accepted off the pose up to "
                        f"{off_pose:.3f} rad)"
                    )
            if now > deadline:
                return None, (
                    f"did not reach the pose within {timeout_s:.1f} s: {name} is "
                    f"{err[worst]:.3f} rad away (tolerance {tol:.4f} rad)"
                )
            next_t += period
            if lockstep_s is None:
                time.sleep(max(0.0, next_t - time.monotonic()))

    def _ramp(self, goal: np.ndarray, speed_rad_s: float | None, period_s: float) -> np.ndarray:
        """The next command towards ``goal``: no further than ``speed_rad_s`` per period."""
        if speed_rad_s is None or self._last_sent is None:
            return goal
        reach = speed_rad_s * period_s
        return self._last_sent + np.clip(goal - self._last_sent, -reach, reach)

    def _walk_read(self, fault: bool) -> ArmState:
        """A reading for a walk: the public one (stall checks), or inside a fault stop the
        plain one (its walk judges "cannot move" itself)."""
        if not fault:
            return self.read_state()
        with self._lock:
            self._require_connected()
            return self._read_state()

    def _say_unwatched(self, state: ArmState) -> None:
        """Once per connection: which joints read their command, so a stall there goes unseen."""
        blind = ~state.measured_mask & self._stall.watched
        if self._said_unwatched or not np.any(blind):
            return
        self._said_unwatched = True
        names = [n for n, b in zip(self.spec.actuator_names, blind, strict=True) if b]
        log.warning(
            "%s read their commands (no sensor on the horn): a stall or a jam there cannot be "
            "felt, only the measured joints are watched",
            ", ".join(names),
        )

    def _say_unfelt(self, unfelt: np.ndarray, model_s: np.ndarray) -> None:
        """Say that the arrival of joints that read their command was assumed, not seen."""
        if not np.any(unfelt):
            return
        names = [n for n, u in zip(self.spec.actuator_names, unfelt, strict=True) if u]
        level = logging.INFO if self._said_unfelt else logging.WARNING
        self._said_unfelt = True
        log.log(
            level,
            "%s read their commands: arrival assumed after %.2f s, the servo model's time for "
            "this move; a lag, droop or jam there cannot be felt",
            ", ".join(names),
            float(np.max(model_s[unfelt])),
        )

    def home(self) -> ArmState:
        """Enable if needed and move to ``spec.actuator_home_rad`` through the step clamp."""
        return self.move_to(self.spec.actuator_home_rad)

    def park(self) -> ArmState:
        """Move to the rest pose (``spec.actuator_park_rad``): call before close() so the arm
        is down when torque goes off."""
        return self.move_to(self.spec.actuator_park_rad)

    # ---- faults ---------------------------------------------------------------------------
    def _fault_stop(
        self,
        reason: str,
        held: np.ndarray | None = None,
        state: ArmState | None = None,
        reenable: bool = False,
    ) -> str:
        """The safe state while the link is alive: hold the pose (a stalled joint where it is,
        so it stops pushing), then park slowly along the safety filter with the torque on, and
        latch ``reason`` (command() refuses until enable(); the pose is kept by resending it).
        Torque goes off only where the arm cannot move there. Returns ``reason`` with how it
        ended, one line."""
        with self._lock:
            if self._in_fault or not self._connected:
                return reason
            self._in_fault = True
            self._keeper_token += 1
            if self._watchdog is not None:
                self._watchdog.disarm()
            log.warning("fault: %s: holding, then parking slowly", reason)
            if self.last_fault is None or self.last_fault[1] != reason:
                self.last_fault = (time.monotonic(), reason)
            self._estop_reason = reason
            self._estop_by_operator = False
        outcome = ""
        try:
            if reenable:
                self.enable()
                with self._lock:
                    self._estop_reason = reason
                    if self._watchdog is not None:
                        self._watchdog.disarm()
            with self._lock:
                self._fault_token = self._keeper_token
            if not self._enabled:
                outcome = "torque was already off"
            else:
                outcome = self._hold_then_park(held, state)
        except _FaultSupersededError:  # (finally clears the fault state)
            log.warning("fault stop (%s) ended early: the arm was re-enabled or stopped", reason)
            return f"{reason}; the hold and park ended early: the arm was taken over"
        except HardwareError as exc:
            outcome = f"could not hold and park ({exc})"
        finally:
            with self._lock:
                self._in_fault = False
                self._fault_token = None
        with self._lock:
            if self._estop_by_operator:  # a person's e-stop cut in: theirs is the last word
                return f"{reason}; stopped by an e-stop ({self._estop_reason}): torque is off"
            if outcome:
                with contextlib.suppress(HardwareError):
                    self._set_torque(False, None)
                self._enabled = False
                return f"{reason}; {outcome}: torque is off"
            self._start_keeper()
            return f"{reason}; held, then parked slowly (torque on, holding: enable() to resume)"

    def _hold_then_park(self, held: np.ndarray | None, state: ArmState | None) -> str:
        """Hold for ``hold_before_disable_s``, then park at ``park_speed_rad_s``; "" when parked,
        else why the arm cannot move."""
        assert self._last_sent is not None
        hold = self._last_sent.copy()
        held_mask = np.zeros(self.spec.n_actuators, bool) if held is None else held
        if np.any(held_mask):
            now = state if state is not None else self._walk_read(True)
            hold = np.where(held_mask, self.safety.clip_to_limits(now.positions_rad), hold)
        end = time.monotonic() + self.spec.safety.hold_before_disable_s
        while True:
            with self._lock:
                self._check_fault_owner()
                if not (self._connected and self._enabled) or self._estop_by_operator:
                    raise SafetyError("the hold was interrupted (torque off or an e-stop)")
                self._filtered_send(hold)
            remaining = end - time.monotonic()
            if remaining <= 0:
                break
            time.sleep(min(_HOLD_RESEND_S, remaining))
        park = self.spec.actuator_park_rad
        timeout_s = 5.0 + float(np.max(np.abs(park - hold)) / park_speed_rad_s(self.spec))
        _, failure = self._walk(
            park,
            off_pose_limit_rad(self.spec),
            timeout_s,
            50.0,
            park_speed_rad_s(self.spec),
            held=held_mask,
            fault=True,
        )
        return f"it cannot move ({failure})" if failure else ""

    def _after_reset(self, exc: DeviceResetError, was_on: bool) -> str:
        """A device that rebooted under a live link (a brown-out) while the arm was working: its
        torque is off and the arm sags. Switch it back on where it is (or was last sent), hold,
        park slowly. Returns the one-line reason."""
        if not was_on or self._in_fault or self._estop_by_operator:
            return str(exc)
        self._enabled = False
        return self._fault_stop(str(exc).split("; call enable()")[0], reenable=True)

    def _check_fault_owner(self) -> None:
        """Inside a fault stop's hold or park (lock held): raise if the arm was taken over."""
        if self._fault_token is not None and self._fault_token != self._keeper_token:
            raise _FaultSupersededError

    def _start_keeper(self) -> None:
        """Resend the held pose every ``_KEEP_S`` while a fault latch holds the arm up, so no
        device watchdog lets go under it; enable(), disable(), estop() and close() end it."""
        self._keeper_token += 1
        token = self._keeper_token

        def keep() -> None:
            while True:
                time.sleep(_KEEP_S)
                with self._lock:
                    if token != self._keeper_token or not (self._connected and self._enabled):
                        return
                    if self._last_sent is None:
                        return
                    try:
                        self._send_targets(self._last_sent)
                    except HardwareError as exc:
                        log.warning("holding after a fault failed: %s", exc)
                        return

        threading.Thread(target=keep, name=f"{type(self).__name__}-keeper", daemon=True).start()

    # ---- e-stop ---------------------------------------------------------------------------
    def estop(self, reason: str = "e-stop", *, operator: bool = False) -> None:
        """Hold the last targets for ``safety.hold_before_disable_s``, then torque off. Latches:
        command() refuses until enable(). ``operator``: a person pressed it (a key, a button),
        so ``move_to``/``home`` refuse too instead of re-enabling, as they do after a watchdog
        or a fault: only an explicit ``enable()`` moves the arm again. Faults the arm can ride
        out (a stall, a missed pose, the host loop stalling) keep it up instead: they hold and
        park slowly (``read_state``, ``move_to``, the host watchdog)."""
        with self._lock:
            if not self._connected:
                return
            self._keeper_token += 1
            self._estop_reason = reason
            self._estop_by_operator = operator
            if self._watchdog is not None:
                self._watchdog.disarm()
            log.warning("e-stop: %s: holding, then torque off", reason)
            if self._enabled and self._last_sent is not None:
                # keep re-sending the hold so device-side watchdogs (a Maestro's serial
                # timeout) do not let go early
                end = time.monotonic() + self.spec.safety.hold_before_disable_s
                try:
                    while True:
                        self._send_targets(self._last_sent)
                        remaining = end - time.monotonic()
                        if remaining <= 0:
                            break
                        time.sleep(min(_HOLD_RESEND_S, remaining))
                except HardwareError as exc:
                    log.warning("e-stop hold failed: %s", exc)
            try:
                self._set_torque(False, None)
            except HardwareError as exc:
                log.warning("e-stop torque-off failed: %s", exc)
            self._enabled = False

    def _on_watchdog(self) -> None:
        """The control loop stopped calling command() but the host and the link are alive:
        hold, then park slowly, torque on (the firmware's own watchdog drops the arm only when
        the host is gone)."""
        timeout = self._watchdog.timeout_s if self._watchdog is not None else 0.0
        if self._enabled and self._estop_reason is None:
            self._fault_stop(f"host watchdog: no command() for {timeout:.2f} s")
