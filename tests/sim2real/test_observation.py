"""The observation/action contract: layout, validation, decoding."""

from __future__ import annotations

import numpy as np
import pytest

from hardware.spec import load_spec
from sim2real.errors import ConfigError
from sim2real.observation import ActionDecoder, ObservationBuilder, ObsField

SPEC = load_spec()


def test_builder_places_fields_in_documented_order_and_split_inverts() -> None:
    b = ObservationBuilder((ObsField("a", 2, "rad", "x"), ObsField("b", 3, "m", "y")))
    obs = b.build({"a": np.array([1, 2]), "b": np.array([3, 4, 5])})
    np.testing.assert_array_equal(obs, [1, 2, 3, 4, 5])
    assert obs.dtype == np.float32
    assert [(f.name, f.start, f.stop) for f in b.layout()] == [("a", 0, 2), ("b", 2, 5)]
    np.testing.assert_array_equal(b.split(obs)["b"], [3, 4, 5])


def test_builder_refuses_missing_or_missized_readings() -> None:
    b = ObservationBuilder((ObsField("a", 2, "rad", "x"),))
    with pytest.raises(ConfigError, match="reading 'a' missing"):
        b.build({})
    with pytest.raises(ConfigError, match="wrong sizes"):
        b.build({"a": np.zeros(3)})
    with pytest.raises(ConfigError, match="unique"):
        ObservationBuilder((ObsField("a", 1, "", ""), ObsField("a", 1, "", "")))


def test_decoder_adds_scaled_deltas_clips_to_limits_and_maps_gripper() -> None:
    dec = ActionDecoder(SPEC, max_delta_rad=0.1, use_gripper=True)
    prev = SPEC.actuator_home_rad.copy()
    prev[0] = SPEC.upper_rad[0] - 0.05
    out = dec.decode(np.array([1.0, -0.5, 7.0, -1.0]), prev)
    assert out[0] == SPEC.upper_rad[0]  # clipped to the limit
    assert out[1] == pytest.approx(prev[1] - 0.05)
    assert out[2] == pytest.approx(prev[2] + 0.1)  # action clipped to 1 first
    assert out[3] == SPEC.gripper.closed_rad
    with pytest.raises(ConfigError, match="safety.max_step_rad"):
        ActionDecoder(SPEC, max_delta_rad=1.0)
