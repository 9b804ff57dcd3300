"""The mock world's physics drives the arm as servos drive horns: the emulator's setpoints are the
targets of the twin's torque-limited actuators, and the servos read back where MuJoCo holds the
horns, through the bytes on the pty."""

from __future__ import annotations

from collections.abc import Iterator

import mujoco
import numpy as np
import pytest

from hardware.emulator import Emulator
from hardware.serial_arm import SerialArm
from hardware.spec import ArmSpec
from sim2real.deploy.worlds import MockPhysics
from sim2real.model import ArmTwin, build_model


@pytest.fixture
def coupled(spec: ArmSpec) -> Iterator[tuple[Emulator, MockPhysics]]:
    emu = Emulator(spec, "feetech")  # STS servos: no watchdog to feed between commands
    emu.start()
    physics = MockPhysics(spec, "reach", emu)
    physics.start()
    try:
        yield emu, physics
    finally:
        physics.close()
        emu.stop()


def _settled(emu: Emulator, physics: MockPhysics) -> np.ndarray:
    """The horns' angles once physics has them at rest (a second of simulated time at least)."""
    start = physics.steps

    def still() -> bool:
        with physics.lock:
            moving = np.abs(physics.twin.actuator_velocities(physics.data)).max()
            return physics.steps - start > 500 and moving < 1e-4

    assert emu.wait_until(still, timeout_s=120.0), "the arm never came to rest"
    with physics.lock:
        return physics.twin.actuator_positions(physics.data).copy()


def test_the_arm_sags_under_gravity_as_the_envs_actuators_do_and_reads_there(
    spec: ArmSpec, coupled: tuple[Emulator, MockPhysics]
) -> None:
    emu, physics = coupled
    goal = spec.actuator_park_rad.copy()
    goal[1], goal[2] = 0.9, 0.2  # forearm reaching out: the shoulder carries the most load
    # no host watchdog: the test waits on physics, however slowly a loaded machine runs it
    with SerialArm(spec, emu.port, protocol="feetech", timeout_s=0.2, host_watchdog_s=None) as arm:
        arm.enable()
        for _ in range(200):
            sent = arm.command(goal)
            if np.allclose(sent, goal, atol=0.002):
                break
        assert np.allclose(sent, goal, atol=0.002)
        horn = _settled(emu, physics)
        reading = arm.read_state().positions_rad

    # the servos drive to the command, but the horns sag: a position actuator with the servo's
    # stall torque holds a load only with an error, and gravity pulls the shoulder down
    setpoint = emu.setpoints_rad()
    np.testing.assert_allclose(setpoint, sent, atol=spec.servo.deadband_rad + 1e-9)
    assert abs(setpoint[1] - horn[1]) > 0.005
    # the host reads where physics holds the horns (to the bus's resolution), not the setpoint
    np.testing.assert_allclose(reading, horn, atol=0.003)
    np.testing.assert_allclose(emu.true_positions_rad(), horn, atol=1e-9)

    # the same sag as the env's arm: its model, driven to the same setpoint, rests there too
    model = build_model(spec, "reach")
    data = mujoco.MjData(model)
    twin = ArmTwin(model, spec)
    twin.set_pose(data, setpoint, float(setpoint[-1]))
    twin.write_ctrl(data, setpoint[: spec.n_joints], float(setpoint[-1]))
    for _ in range(3000):
        mujoco.mj_step(model, data)
    np.testing.assert_allclose(horn, twin.actuator_positions(data), atol=2e-3)
