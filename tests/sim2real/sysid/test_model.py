"""sysid's compiled integrator is the one servo model (``hardware.servo_model``), not a copy."""

from __future__ import annotations

import numpy as np
import pytest

from sim2real.sysid.model import SIM_DT_S, ServoFit, simulate

FITS = [
    ServoFit(time_constant_s=0.05, max_speed_rad_s=2.0, deadband_rad=0.01, latency_s=0.0),
    ServoFit(
        time_constant_s=0.03,
        max_speed_rad_s=5.0,
        deadband_rad=0.002,
        latency_s=0.0237,
        droop_rad=-0.03,
    ),
    ServoFit(time_constant_s=0.2, max_speed_rad_s=0.8, deadband_rad=0.0, latency_s=0.0611),
]


@pytest.mark.parametrize("fit", FITS)
def test_compiled_simulation_equals_the_numpy_servo_model(fit: ServoFit) -> None:
    """Irregular command and read times (as a host log has them), steps big enough to hit the
    rate limit and small enough to sit in the dead band, a latency that is not a whole number
    of integration steps."""
    rng = np.random.default_rng(18)
    t_cmd = np.cumsum(rng.uniform(0.02, 0.07, 40))  # > SIM_DT_S apart, as on any real bus
    u = np.cumsum(rng.choice([-0.4, -0.005, 0.0, 0.005, 0.4], (40, 3)), axis=0)
    t_read = np.sort(rng.uniform(t_cmd[0] - 0.05, t_cmd[-1] + 0.3, 300))
    x0 = np.array([0.1, -0.2, 0.0])
    mask = np.array([0.0, 1.0, 1.0])
    fast = simulate(fit, t_cmd, u, t_read, x0, mask)
    ref = simulate(fit, t_cmd, u, t_read, x0, mask, engine="model")
    assert np.ptp(ref, axis=0).min() > 0.2  # the joints really moved
    np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-9)


def test_reference_differs_when_the_model_does() -> None:
    """The comparison above can fail: a latency of one integration step more is visible."""
    fit = FITS[1]
    t_cmd = np.arange(0.0, 1.0, 0.05)
    u = np.repeat(np.linspace(0.0, 1.0, len(t_cmd))[:, None], 2, axis=1)
    t_read = np.arange(0.0, 1.2, 0.01)
    later = ServoFit(**{**fit.__dict__, "latency_s": fit.latency_s + SIM_DT_S})
    a = simulate(fit, t_cmd, u, t_read, np.zeros(2), np.ones(2))
    b = simulate(later, t_cmd, u, t_read, np.zeros(2), np.ones(2), engine="model")
    assert np.abs(a - b).max() > 1e-4
