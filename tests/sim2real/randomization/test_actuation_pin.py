"""The env's actuation is bit-for-bit what the reach/pick policies were trained and measured on.

The expected outputs were recorded before the servo model moved to ``hardware.servo_model``
(see ``tests/data/actuation_pin/README.md``); any change to the per-step actuation shows here.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hardware.spec import load_spec
from sim2real.actuation import ServoActuation

PIN = Path(__file__).parents[2] / "data" / "actuation_pin" / "servo_actuation_v1.npz"
# none, then the default, shifted and strong presets at (or near) their edges
CASES = [
    (0, 0.0, 1.0, 0.0, 0.0),
    (1, 0.005, 0.6, 0.004, 0.0016),
    (2, 0.008, 0.45, 0.013, 0.0016),
    (2, 0.01, 0.4, 0.015, 0.0032),
]
KEYS = ("latency_steps", "action_noise_rad", "max_speed_scale", "deadband_rad", "quantisation_rad")


def test_per_step_actuation_matches_the_recorded_sequence() -> None:
    pinned = np.load(PIN)
    cmds, expected = pinned["cmds"], pinned["outs"]
    spec = load_spec()
    for case, values in enumerate(CASES):
        servo = ServoActuation(spec, 0.05, 3)
        servo.configure(dict(zip(KEYS, values, strict=True)))
        servo.reset(np.array([0.1, -0.2, 0.3]))
        rng = np.random.default_rng(7)
        got = []
        for i, cmd in enumerate(cmds):
            if i == 100:
                servo.reset(cmd)
            got.append(servo(cmd.copy(), rng).copy())
        np.testing.assert_array_equal(np.array(got), expected[case], err_msg=f"case {values}")
