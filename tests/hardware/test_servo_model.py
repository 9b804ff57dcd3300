"""The one servo model's pieces do what the emulator, the sim and sysid rely on."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hardware.servo_model import CommandDelay, ServoBank, ServoParams, StepServo, quantise
from hardware.spec import load_spec

SPEC = load_spec()


def test_reading_quantisation_is_the_emulators_rounding_to_the_bit() -> None:
    """Readings round ``x / resolution`` (ties to even), as the emulator always has: a servo
    parked on a tie reads the same as before the model moved here."""
    res = SPEC.servo.resolution_rad
    x = np.array([-0.3, 0.9, 0.5 * res, 1.5 * res, -2.5 * res, 0.123456])
    np.testing.assert_array_equal(quantise(x, res), np.round(x / res) * res)
    np.testing.assert_array_equal(quantise(x, 0.0), x)


def test_command_delay_splits_an_interval_where_targets_come_due() -> None:
    delay = CommandDelay()
    delay.in_force = np.zeros(1)
    delay.push(0.013, np.ones(1))
    delay.push(0.017, np.full(1, 2.0))
    pieces = [
        (round(dt, 9), None if t is None else float(t[0])) for dt, t in delay.segments(0.01, 0.02)
    ]
    assert pieces == [(0.003, 0.0), (0.004, 1.0), (0.003, 2.0)]
    assert delay.last() is not None and float(delay.last()[0]) == 2.0


def test_a_latent_servo_is_the_prompt_one_shifted_by_the_latency() -> None:
    """Continuous-time latency: the same command history, seen ``latency`` later."""
    powered = np.ones(SPEC.n_actuators, dtype=bool)
    start = SPEC.actuator_park_rad
    prompt = ServoBank(ServoParams.from_spec(SPEC), start)
    late = ServoBank(ServoParams.from_spec(SPEC, command_latency_s=0.03), start)
    goal = start + np.array([0.4, -0.2, 0.3, 0.0])
    late.advance(0.0, 0.001, start, powered)  # the power-on goal: holds the start
    late.advance(0.001, 0.01, goal, powered)
    late.advance(0.01, 0.031, goal, powered)  # the goal takes effect at 0.031
    trace_late, trace_prompt = [], []
    for k in range(20):
        late.advance(0.031 + 0.01 * k, 0.041 + 0.01 * k, goal, powered)
        prompt.advance(0.01 * k, 0.01 * (k + 1), goal, powered)
        trace_late.append(late.pos.copy())
        trace_prompt.append(prompt.pos.copy())
    np.testing.assert_allclose(trace_late, trace_prompt, atol=1e-12)
    assert np.abs(trace_prompt[-1] - start).max() > 0.1  # it really moved


def test_step_servo_holds_small_changes_and_limits_big_ones() -> None:
    servo = StepServo(2, max_speed_rad_s=2.0, control_dt_s=0.05)
    servo.set(latency_steps=1, deadband_rad=0.01, resolution_rad=0.002)
    servo.reset(np.zeros(2))
    assert np.array_equal(servo.step(np.array([0.5, 0.005])), [0.0, 0.0])  # latency: old target
    np.testing.assert_allclose(servo.step(np.array([0.5, 0.005])), [0.1, 0.0])  # rate, dead band


def test_emulator_servos_match_the_recorded_dynamics_to_the_bit() -> None:
    """The emulator's servos behave exactly as before the model moved (see
    ``tests/data/actuation_pin/README.md``): positions and noisy, quantised readings."""
    pin = np.load(Path(__file__).parents[1] / "data" / "actuation_pin" / "emulator_servos_v1.npz")
    for name, latency_s in (("prompt", 0.0), ("latent", 0.023)):
        bank = ServoBank(
            ServoParams.from_spec(SPEC, 0.02, 0.003, latency_s), SPEC.actuator_park_rad, seed=3
        )
        t, pos, reading = 0.0, [], []
        for k, dt in enumerate(pin["dt"]):
            bank.advance(t, t + dt, pin["targets"][k], pin["powered"][k])
            t += dt
            if k == 200:
                bank.drop_pending()
            pos.append(bank.pos.copy())
            reading.append(bank.reading_rad())
        # to a rounding: the pin was recorded on a CPU whose numpy and BLAS kernels (AVX-512,
        # FMA) round the last bit differently from others' (found on an AVX2-only EPYC)
        np.testing.assert_allclose(np.array(pos), pin[f"{name}_pos"], rtol=1e-13, atol=1e-15)
        np.testing.assert_array_equal(np.array(reading), pin[f"{name}_reading"], err_msg=name)
