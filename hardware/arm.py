"""The Arm interface every backend implements, and the base class that puts safety in front.

``ArmBase`` does the bookkeeping once (connection state, the safety filter, the host watchdog,
e-stop, torque-off on close) and calls a handful of protected hooks that a backend implements:
``_connect``, ``_close``, ``_read_state``, ``_send_targets``, ``_set_torque``. The serial backend
(``SerialArm``) and the MuJoCo backend (``SimArm``) both derive from it, so neither can skip the
safety layer, and one contract test suite (tests/hardware/arm_contract.py) checks both.
"""

from __future__ import annotations

import logging
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Protocol, TypeVar, runtime_checkable

import numpy as np

from hardware.errors import HardwareError, NotConnectedError, SafetyError
from hardware.safety import SafetyFilter, Watchdog
from hardware.spec import ArmSpec

log = logging.getLogger(__name__)

_A = TypeVar("_A", bound="ArmBase")
_SPEC_DEFAULT = -1.0  # sentinel: take the host watchdog timeout from the spec
_HOLD_RESEND_S = 0.05  # during an e-stop hold, resend the targets this often


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
        with self._lock:
            self._require_connected()
            return self._read_state()

    def command(self, targets_rad: Any) -> np.ndarray:
        """Filter ``targets_rad`` through safety, send it, return what actually went out."""
        with self._lock:
            self._require_connected()
            if self._estop_reason is not None:
                raise SafetyError(f"e-stop latched ({self._estop_reason}); call enable() to resume")
            if not self._enabled:
                raise SafetyError("torque is off: call enable() (or home()) before command()")
            assert self._last_sent is not None
            safe = self.safety.filter(targets_rad, self._last_sent)
            sent = np.asarray(self._send_targets(safe), dtype=float)
            self._last_sent = sent.copy()
            if self._watchdog is not None:
                self._watchdog.kick()
            return sent

    def hold(self) -> np.ndarray:
        """Resend the last targets: keeps every watchdog fed without moving (jog, prompts)."""
        with self._lock:
            assert self._last_sent is not None or not self._connected
            return self.command(self._last_sent)

    def enable(self) -> None:
        """Torque on at the pose the device holds now; clears a latched e-stop."""
        with self._lock:
            self._require_connected()
            self._before_enable()
            state = self._read_state()
            self._set_torque(True, self._reference(state))
            self._last_sent = self._reference(self._read_state())
            self._enabled = True
            self._estop_reason = None
            self._estop_by_operator = False
            if self._watchdog is not None:
                self._watchdog.arm()

    def _before_enable(self) -> None:  # noqa: B027 - an optional hook, empty by default
        """Hook: re-synchronise after a device reset (SerialArm)."""

    def disable(self) -> None:
        with self._lock:
            self._require_connected()
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
    ) -> ArmState:
        """Walk to ``target_rad`` through the per-step clamp at ``rate_hz``; return the state once
        every actuator is within ``tolerance_rad`` (default: ``arrival_tolerance_rad(spec)``,
        from the servo figures, which sysid's fitted spec carries).

        An arm that stops short (droop, a wider dead band than the spec says) but within
        ``off_pose_limit_rad(spec)`` is warned about and returned: it works, a little off. One
        that stops further away, or is still away at ``timeout_s``, is e-stopped (hold, then
        torque off) and raises HardwareError."""
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
        tol = arrival_tolerance_rad(self.spec) if tolerance_rad is None else float(tolerance_rad)
        off_pose = max(off_pose_limit_rad(self.spec), tol)
        window_s = settle_window_s(self.spec)
        progress_rad = self.spec.servo.resolution_rad + 0.25 * tol  # less is noise, not motion
        period = 1.0 / rate_hz
        start = time.monotonic()
        deadline = start + timeout_s
        next_t = start
        prev_sent: np.ndarray | None = None
        best = np.full(self.spec.n_actuators, np.inf)
        last_progress_t = start
        while True:
            sent = self.command(target)
            state = self.read_state()
            now = time.monotonic()
            err = np.abs(state.positions_rad - target)
            worst = int(np.argmax(err))
            name = self.spec.actuator_names[worst]
            # the targets sit on the goal once the step clamp no longer moves them
            settled_targets = prev_sent is not None and np.array_equal(sent, prev_sent)
            prev_sent = sent
            if not settled_targets:
                best[:] = np.inf
                last_progress_t = now
            else:
                if np.all(err <= tol):
                    return state
                improved = err < best - progress_rad  # against the last progress, so a slow
                if np.any(improved):  # but moving arm adds up to progress within the window
                    last_progress_t = now
                best = np.where(improved, err, best)
                if now - last_progress_t >= window_s:  # stopped moving, short of the pose
                    if np.all(err <= off_pose):
                        log.warning(
                            "settled %.3f rad off the pose at %s (arrival tolerance %.4f rad): "
                            "droop or a dead band the spec does not describe; `sim2real sysid` "
                            "fits them",
                            err[worst],
                            name,
                            tol,
                        )
                        return state
                    reason = (
                        f"did not reach the pose: {name} stopped {err[worst]:.3f} rad away "
                        f"(arrival tolerance {tol:.4f} rad, accepted off the pose up to "
                        f"{off_pose:.3f} rad); torque is off"
                    )
                    self.estop(reason)
                    raise HardwareError(reason)
            if now > deadline:
                reason = (
                    f"did not reach the pose within {timeout_s:.1f} s: {name} is "
                    f"{err[worst]:.3f} rad away (tolerance {tol:.4f} rad); torque is off"
                )
                self.estop(reason)
                raise HardwareError(reason)
            next_t += period
            time.sleep(max(0.0, next_t - time.monotonic()))

    def home(self) -> ArmState:
        """Enable if needed and move to ``spec.actuator_home_rad`` through the step clamp."""
        return self.move_to(self.spec.actuator_home_rad)

    def park(self) -> ArmState:
        """Move to the rest pose (``spec.actuator_park_rad``): call before close() so the arm
        is down when torque goes off."""
        return self.move_to(self.spec.actuator_park_rad)

    # ---- e-stop ---------------------------------------------------------------------------
    def estop(self, reason: str = "e-stop", *, operator: bool = False) -> None:
        """Hold the last targets for ``safety.hold_before_disable_s``, then torque off. Latches:
        command() refuses until enable(). ``operator``: a person pressed it (a key, a button),
        so ``move_to``/``home`` refuse too instead of re-enabling, as they do after a watchdog
        or a fault: only an explicit ``enable()`` moves the arm again."""
        with self._lock:
            if not self._connected:
                return
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
        timeout = self._watchdog.timeout_s if self._watchdog is not None else 0.0
        self.estop(f"host watchdog: no command() for {timeout:.2f} s")
