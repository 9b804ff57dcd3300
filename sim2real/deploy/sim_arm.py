"""``SimArm``: the ``hardware.Arm`` interface on MuJoCo physics.

It derives from ``hardware.arm.ArmBase``, so the same safety filter, e-stop and lifecycle sit in
front of it as in front of a real servo bus, and it passes the same contract test suite. Servo
behaviour between the command and the horn comes from the same ``ServoActuation`` layer the envs
use. Time: ``clock="lockstep"`` advances one control period per command (fast, deterministic:
``lockstep_period_s`` and ``now_s`` tell the loop and ``move_to`` to run on this time, unslept);
``clock="realtime"`` steps physics to catch up with the wall clock on every call, as a real arm
keeps moving while the host thinks.

Between episodes (``move_to``: home, park) a free finger caught in the model's numerical limit
cycle is set at rest where its actuator drives it; see ``FINGER_CYCLE_SPEED_M_S``.

Readings follow the spec's kinds (``hardware.spec.FEEDBACK_KINDS``), as the envs' sensor model
does: a measured actuator reads its joint; a commanded one (bare PWM servos) reads what the board
last output, its targets slewed at the spec's speeds in simulated time (the firmware's slew-rate
limit), whatever the joint does; ``ArmState.measured`` says which.
"""

from __future__ import annotations

import time
from collections import deque
from typing import Any

import mujoco
import numpy as np

from hardware.arm import ArmBase, ArmState
from hardware.spec import ArmSpec
from sim2real.actuation import ServoActuation
from sim2real.camera_rig import RigSpec
from sim2real.errors import UnknownNameError
from sim2real.scene_names import FINGER_GEOMS, FINGER_JOINTS
from sim2real.twin import ArmTwin
from sim2real.twin_mjcf import build_model

CLOCKS = ("lockstep", "realtime")
# The finger actuator's damping (kv) is stiff for the 5 ms step and counts inside its force
# clamp; once the clamp saturates, MuJoCo's implicit integration no longer covers it and a free
# finger can lock into a two-step limit cycle (measured: +-0.86 m/s, 4 mm apart, forever, 105 of
# 200 random gripper moves in free air). The env has the same model, and the shipped policy was
# trained on it, so episodes keep it; but a cycle entered when a held cube drops at homing never
# reaches the home opening (an even number of steps per command samples one phase: "gripper
# stopped 0.47 rad away"). A servo-driven finger that still moves this fast a whole period
# after its last command is in that cycle, not on its way.
FINGER_CYCLE_SPEED_M_S = 0.3


class SimArm(ArmBase):
    """A simulated arm: torque off really lets it sag under gravity."""

    def __init__(
        self,
        spec: ArmSpec,
        *,
        scene: str = "reach",
        rig: RigSpec | None = None,
        control_hz: float = 20.0,
        clock: str = "lockstep",
        max_step_rad: float | None = None,
        on_nonfinite: str = "hold",
    ) -> None:
        if clock not in CLOCKS:
            raise UnknownNameError("clock", clock, CLOCKS)
        # No host watchdog: in lockstep, simulated time does not pass between commands.
        super().__init__(
            spec, max_step_rad=max_step_rad, on_nonfinite=on_nonfinite, host_watchdog_s=None
        )
        self.model = build_model(spec, scene, rig)
        self.data = mujoco.MjData(self.model)
        self.twin = ArmTwin(self.model, spec)
        self.clock = clock
        self.control_dt_s = 1.0 / control_hz
        self.frame_skip = max(1, round(self.control_dt_s / self.model.opt.timestep))
        self.servo = ServoActuation(spec, self.control_dt_s, spec.n_joints)
        n = spec.n_joints
        self._gain = self.model.actuator_gainprm[:, 0].copy()
        self._bias = self.model.actuator_biasprm[:, :3].copy()
        self._targets = spec.actuator_park_rad.copy()
        self._n = n
        # commanded readings: the board's output (rad) and when it was last slewed (sim time)
        self._measured = spec.actuator_measured
        self._echo_measured = None if bool(self._measured.all()) else self._measured
        speeds = [spec.servo.max_speed_rad_s] * n
        if spec.gripper is not None:
            speeds.append(spec.gripper.max_speed_rad_s)
        self._slew_rad_s = np.array(speeds)
        self._echo = self._targets.copy()
        self._echo_t = 0.0
        self._wall_t0 = 0.0
        self._moving = False  # inside move_to (home, park): between episodes
        if self.twin.has_gripper:
            self._finger_dofs = np.array([self.model.joint(j).dofadr[0] for j in FINGER_JOINTS])
            self._finger_geoms = frozenset(self.model.geom(g).id for g in FINGER_GEOMS)
        # Every target vector applied, oldest first (bounded): what the contract tests compare
        # with what command() returned. Appended under the base's lock (a keeper thread sends
        # too), so it is read through received_targets_rad().
        self._received: deque[np.ndarray] = deque(maxlen=10_000)

    # ---- time -------------------------------------------------------------------------------
    def _advance(self, seconds: float) -> None:
        steps = int(seconds / self.model.opt.timestep)
        if steps > 0:
            mujoco.mj_step(self.model, self.data, nstep=steps)
            self._settle_fingers()

    def _settle_fingers(self) -> None:
        """Between episodes only: a free finger in the limit cycle (``FINGER_CYCLE_SPEED_M_S``)
        is put at rest where its actuator drives it, as a real gripper's would be."""
        if not (self._moving and self.twin.has_gripper):
            return
        d = self.data
        if np.max(np.abs(d.qvel[self._finger_dofs])) < FINGER_CYCLE_SPEED_M_S:
            return
        geoms = self._finger_geoms
        for i in range(d.ncon):  # a finger on something: the contact decides, not the actuator
            if int(d.contact[i].geom1) in geoms or int(d.contact[i].geom2) in geoms:
                return
        d.qpos[self.twin.finger_qadr] = d.ctrl[self.twin.n_joints]
        d.qvel[self._finger_dofs] = 0.0
        mujoco.mj_forward(self.model, d)

    def _catch_up(self) -> None:
        if self.clock == "realtime":
            behind = (time.monotonic() - self._wall_t0) - self.data.time
            self._advance(behind)
        self._slew_echo()

    def _slew_echo(self) -> None:
        """The board's output pulses slewed towards the targets up to now (simulated time)."""
        dt = self.data.time - self._echo_t
        self._echo_t = self.data.time
        if self._echo_measured is None or dt <= 0 or not self.torque_on:
            return
        d = self._targets - self._echo
        self._echo = self._echo + np.clip(d, -self._slew_rad_s * dt, self._slew_rad_s * dt)

    # ---- hooks ------------------------------------------------------------------------------
    def _connect(self) -> None:
        mujoco.mj_resetData(self.model, self.data)
        park = self.spec.actuator_park_rad
        grip = float(park[-1]) if self.twin.has_gripper else None
        self.twin.set_pose(self.data, park, grip)
        self._set_torque(False, None)
        mujoco.mj_forward(self.model, self.data)
        self._wall_t0 = time.monotonic()
        self._echo, self._echo_t = park.copy(), float(self.data.time)

    def _close(self) -> None:
        """Nothing to release: the model stays inspectable after close."""

    def _read_state(self) -> ArmState:
        self._catch_up()
        pos = self.twin.actuator_positions(self.data)
        vel = self.twin.joint_velocities(self.data)
        if self.twin.has_gripper:
            vel = np.append(vel, 0.0)
        if self._echo_measured is not None:  # what the board sent, not where the joint is
            pos = np.where(self._measured, pos, self._echo)
            vel = np.where(self._measured, vel, 0.0)
        res = self.spec.servo.resolution_rad
        if res > 0:  # a servo reports positions in whole encoder / pulse steps
            pos = np.rint(pos / res) * res
        return ArmState(
            positions_rad=pos,
            timestamp_s=float(self.data.time),
            velocities_rad_s=vel,
            measured=self._echo_measured,
        )

    def _send_targets(self, targets_rad: np.ndarray) -> np.ndarray:
        self._catch_up()  # the output slews towards the last targets until now
        self._targets = np.asarray(targets_rad, dtype=float).copy()
        joint_ctrl = self.servo(self._targets[: self._n], np.random.default_rng(0))
        grip = float(self._targets[-1]) if self.twin.has_gripper else None
        self.twin.write_ctrl(self.data, joint_ctrl, grip)
        if self.clock == "lockstep":
            mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
            self._settle_fingers()
        res = self.spec.servo.resolution_rad
        sent = np.rint(self._targets / res) * res if res > 0 else self._targets.copy()
        self._received.append(sent.copy())
        return sent

    def received_targets_rad(self) -> list[np.ndarray]:
        """Every target vector applied so far (the newest 10,000), oldest first."""
        with self._lock:
            return list(self._received)

    @property
    def lockstep_period_s(self) -> float | None:
        return self.frame_skip * self.model.opt.timestep if self.clock == "lockstep" else None

    def now_s(self) -> float:
        if self.clock == "lockstep":
            return float(self.data.time)
        return super().now_s()

    def move_to(self, target_rad: np.ndarray, **kwargs: Any) -> ArmState:
        """``ArmBase.move_to`` (home, park: no policy runs) with the fingers kept out of the
        model's limit cycle."""
        self._moving = True
        try:
            return super().move_to(target_rad, **kwargs)
        finally:
            self._moving = False

    @property
    def torque_on(self) -> bool:
        return bool(np.all(self.model.actuator_gainprm[:, 0] > 0))

    def _set_torque(self, on: bool, hold_rad: np.ndarray | None) -> None:
        m = self.model
        if on:
            m.actuator_gainprm[:, 0] = self._gain
            m.actuator_biasprm[:, :3] = self._bias
            hold = self.twin.actuator_positions(self.data) if hold_rad is None else hold_rad
            self._targets = np.asarray(hold, dtype=float).copy()
            self._echo, self._echo_t = self._targets.copy(), float(self.data.time)  # no snap
            self.servo.reset(self._targets[: self._n])
            grip = float(self._targets[-1]) if self.twin.has_gripper else None
            self.twin.write_ctrl(self.data, self._targets[: self._n], grip)
        else:  # a detached hobby servo applies no torque at all
            m.actuator_gainprm[:, 0] = 0.0
            m.actuator_biasprm[:, :3] = 0.0

    # ---- simulation access (the deploy loop's ground truth) -------------------------------------
    def tool_position(self) -> np.ndarray:
        self._catch_up()
        return self.twin.tool_position(self.data).copy()
