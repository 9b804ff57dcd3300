"""SerialArm: the Arm interface over any servo protocol and any pyserial URL.

    with SerialArm(load_spec(), "/dev/ttyUSB0", protocol="s2r") as arm:
        arm.home()
        sent = arm.command(policy_action_rad)

Between the policy and the wire: the safety filter (NaN hold, joint limits, per-step clamp, in
rad), then the joint calibration into servo units, rounded and clamped again *in units* (limits
rounded inward, the step rounded down) so quantisation can never push a command over a limit or
the clamp. ``command`` returns exactly what went out, converted back to rad.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from hardware.arm import _SPEC_DEFAULT, ArmBase, ArmState
from hardware.errors import DeviceResetError, HardwareError, SafetyError, TorqueOffError
from hardware.joint_calibration import ArmCalibration, nominal_calibration
from hardware.protocols import get_protocol
from hardware.protocols.base import DeviceInfo, Link, Protocol, UnitState
from hardware.spec import ArmSpec


def quantise_targets(
    calibration: ArmCalibration,
    targets_rad: np.ndarray,
    last_units: np.ndarray,
    lower_units: np.ndarray,
    upper_units: np.ndarray,
    step_units: np.ndarray,
) -> np.ndarray:
    """Safe rad targets -> integer servo units, clamped again in units: limits (rounded inward)
    and the step around ``last_units`` (rounded down), so rounding cannot cross either."""
    u = np.rint(calibration.to_units_float(targets_rad)).astype(np.int64)
    u = np.clip(u, lower_units, upper_units)
    return np.clip(u, last_units - step_units, last_units + step_units)


class SerialArm(ArmBase):
    """An arm on a serial port. ``calibration`` is an ArmCalibration, a path to its YAML, or
    None for the nominal datasheet mapping."""

    def __init__(
        self,
        spec: ArmSpec,
        url: str,
        protocol: str = "s2r",
        baud: int | None = None,
        calibration: ArmCalibration | str | os.PathLike[str] | None = None,
        *,
        timeout_s: float = 0.05,
        retries: int = 3,
        push_limits: bool = True,
        exclusive: bool = True,
        max_step_rad: float | None = None,
        on_nonfinite: str = "hold",
        host_watchdog_s: float | None = _SPEC_DEFAULT,
        protocol_options: dict[str, Any] | None = None,
    ) -> None:
        super().__init__(
            spec,
            max_step_rad=max_step_rad,
            on_nonfinite=on_nonfinite,
            host_watchdog_s=host_watchdog_s,
        )
        self.url = url
        self.protocol_cls: type[Protocol] = get_protocol(protocol)
        self.protocol_name = protocol
        self.baud = int(baud) if baud is not None else self.protocol_cls.default_baud
        if self.baud <= 0:
            raise HardwareError(f"baud must be > 0, got {baud!r}")
        frame = self.protocol_cls.unit_frame(spec)
        if calibration is None:
            cal = nominal_calibration(spec, protocol, frame)
        elif isinstance(calibration, ArmCalibration):
            cal = calibration
        else:
            cal = ArmCalibration.load(Path(calibration))
        cal.check_spec(spec)
        cal.check_protocol(protocol, frame)
        self.calibration = cal
        # Checked before any port is touched: a spec whose limits exceed the servo range fails
        # here, with the joint named.
        self.lower_units, self.upper_units = cal.unit_limits(spec)
        self.step_units = cal.max_step_units(self.safety.max_step_rad)
        speeds = [spec.servo.max_speed_rad_s] * spec.n_joints
        if spec.gripper is not None:
            speeds.append(spec.gripper.max_speed_rad_s)
        self.speed_units_per_s = np.array(speeds) * cal.scale_units_per_rad
        self.rest_units = np.clip(
            cal.to_units(spec.actuator_park_rad), self.lower_units, self.upper_units
        )
        self.timeout_s = timeout_s
        self.retries = retries
        self.push_limits = push_limits
        self._exclusive = exclusive
        self._protocol_options = dict(protocol_options or {})
        self.link: Link | None = None
        self.proto: Protocol | None = None
        self.info: DeviceInfo | None = None
        self._last_units = self.rest_units.copy()
        self._last_unit_state: UnitState | None = None
        self._needs_resync = False

    # ---- hooks ----------------------------------------------------------------------------
    def _connect(self) -> None:
        link = Link(self.url, self.baud, self.protocol_cls.make_framer(), exclusive=self._exclusive)
        link.open()
        try:
            proto = self.protocol_cls(
                link,
                self.spec.actuator_ids,
                timeout_s=self.timeout_s,
                retries=self.retries,
                **self._protocol_options,
            )
            proto.rest_units = self.rest_units
            self.info = proto.ping()
            if self.push_limits:
                proto.configure(
                    self.lower_units, self.upper_units, self.step_units, self.speed_units_per_s
                )
        except BaseException:
            link.close()
            raise
        self.link, self.proto = link, proto

    def _close(self) -> None:
        if self.link is not None:
            self.link.close()
        self.link = None
        self.proto = None

    def _p(self) -> Protocol:
        if self.proto is None:
            raise HardwareError("not connected")
        return self.proto

    def _latch(self, exc: HardwareError) -> None:
        """A reset or a device-side watchdog means the servos are limp: refuse commands until
        enable() re-synchronises."""
        self._enabled = False
        self._estop_reason = str(exc)
        self._needs_resync = True
        if self._watchdog is not None:
            self._watchdog.disarm()

    def _to_state(self, us: UnitState) -> ArmState:
        cal = self.calibration
        vel = loads = None
        if us.velocities is not None:
            vel = cal.direction * us.velocities / cal.scale_units_per_rad
        if us.loads is not None:
            loads = cal.direction * us.loads
        measured = us.measured
        if measured is None:  # a protocol that does not say: only its commands are known
            measured = np.zeros(self.spec.n_actuators, dtype=bool)
        return ArmState(
            positions_rad=cal.from_units(us.positions),
            timestamp_s=us.timestamp_s,
            velocities_rad_s=vel,
            loads=loads,
            measured=measured,
        )

    def _read_state(self) -> ArmState:
        try:
            us = self._p().read_state()
        except (DeviceResetError, SafetyError) as exc:
            self._latch(exc)
            raise
        self._last_unit_state = us
        return self._to_state(us)

    def _send_targets(self, targets_rad: np.ndarray) -> np.ndarray:
        cal = self.calibration
        u = quantise_targets(
            cal, targets_rad, self._last_units, self.lower_units, self.upper_units, self.step_units
        )
        try:
            us = self._p().write_targets(u)
        except (DeviceResetError, SafetyError) as exc:
            self._latch(exc)
            raise
        self._last_units = u
        if us is not None:
            self._last_unit_state = us
        return cal.from_units(u)

    def _set_torque(self, on: bool, hold_rad: np.ndarray | None) -> None:
        hold = None
        if hold_rad is not None:
            hold = self._quantise(hold_rad)
            self._last_units = hold
        self._p().set_torque(on, hold)

    def _quantise(self, q_rad: np.ndarray) -> np.ndarray:
        u = np.rint(self.calibration.to_units_float(q_rad)).astype(np.int64)
        return np.clip(u, self.lower_units, self.upper_units)

    def _reference(self, state: ArmState) -> np.ndarray:
        """Start the step clamp from the device's own targets where it reports them (so host
        and firmware clamp around the same point), else from the measured position, or for a
        servo without feedback from the last target sent. ``enable`` hands this to the device as
        the pose to switch on at, so nothing snaps."""
        us = self._last_unit_state
        if us is not None and us.targets is not None and us.torque_on:
            u = np.clip(us.targets, self.lower_units, self.upper_units)
        else:
            # torque off: a measured servo from where it is; one that reads its command from
            # where this host last sent it (after a reboot the device only knows park)
            u = np.where(state.measured_mask, self._quantise(state.positions_rad), self._last_units)
        self._last_units = u.astype(np.int64)
        return self.calibration.from_units(self._last_units)

    def _before_enable(self) -> None:
        proto = self._p()
        if self._needs_resync:
            proto.forget_reset()
            proto.ping()
            if self.push_limits:
                proto.configure(
                    self.lower_units, self.upper_units, self.step_units, self.speed_units_per_s
                )
            self._needs_resync = False

    # ---- extras ---------------------------------------------------------------------------
    def set_pipelined(self, on: bool) -> None:
        """Pipelined commands where the protocol has them (s2r): ``command`` returns once its
        bytes are out and its reply is collected before the next request (a real-time loop
        waits for one round trip a period, its reading). Turning it off collects it now."""
        with self._lock:
            proto = self.proto
            if proto is None or not proto.supports_pipeline:
                return
            proto.pipeline = on
            if not on:
                try:
                    proto.settle()
                except (DeviceResetError, SafetyError) as exc:
                    self._latch(exc)
                    raise

    def ping(self) -> DeviceInfo:
        with self._lock:
            self._require_connected()
            return self._p().ping()

    def heartbeat(self) -> None:
        with self._lock:
            self._require_connected()
            self._p().heartbeat()

    def stats(self) -> dict[str, int]:
        """Host-side counters: link (framer), driver (retries, timeouts), safety."""
        out: dict[str, int] = {}
        if self.link is not None:
            out.update({f"rx_{k}": v for k, v in self.link.framer.stats.as_dict().items()})
            out["bytes_in"], out["bytes_out"] = self.link.bytes_in, self.link.bytes_out
        if self.proto is not None:
            out.update(self.proto.stats.as_dict())
        out.update({f"safety_{k}": v for k, v in self.safety.stats.__dict__.items()})
        return out

    @property
    def last_sent_units(self) -> np.ndarray:
        return self._last_units.copy()

    def read_units(self) -> UnitState:
        """Raw reading in servo units (joint calibration uses it)."""
        with self._lock:
            self._require_connected()
            return self._p().read_state()

    def command_units(
        self, units: np.ndarray, max_step_units: np.ndarray | None = None
    ) -> np.ndarray:
        """Raw servo units, for calibration before the rad mapping is known. Still safe: the
        servo's unit range and a per-step clamp in units apply; returns what went out."""
        with self._lock:
            self._require_connected()
            if not self._enabled:
                raise TorqueOffError("torque is off: call enable() before command_units()")
            req = np.asarray(units, dtype=float)
            if req.shape != (self.spec.n_actuators,) or not np.all(np.isfinite(req)):
                raise SafetyError(
                    f"units must be {self.spec.n_actuators} finite numbers, got {units!r}"
                )
            frame = self.calibration.frame
            step = (
                self.step_units
                if max_step_units is None
                else np.asarray(max_step_units, dtype=np.int64)
            )
            u = np.clip(np.rint(req).astype(np.int64), frame.unit_min, frame.unit_max)
            u = np.clip(u, self._last_units - step, self._last_units + step)
            try:
                us = self._p().write_targets(u)
            except (DeviceResetError, SafetyError) as exc:
                self._latch(exc)
                raise
            self._last_units = u
            self._last_sent = self.calibration.from_units(u)
            if us is not None:
                self._last_unit_state = us
            if self._watchdog is not None:
                self._watchdog.kick()
            return u.copy()
