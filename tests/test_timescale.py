"""``SIM2REAL_TIME_SCALE``: the one factor for the realtime tests' margins, read in one place."""

from __future__ import annotations

import pytest
import timescale


@pytest.mark.parametrize(("text", "factor"), [("", 1.0), ("1", 1.0), ("2.5", 2.5), (" 3 ", 3.0)])
def test_the_scale_widens_margins_by_its_factor(
    monkeypatch: pytest.MonkeyPatch, text: str, factor: float
) -> None:
    monkeypatch.setenv(timescale.ENV_VAR, text)
    assert timescale._read() == factor


@pytest.mark.parametrize("text", ["0.5", "0", "-2", "nan", "inf", "fast"])
def test_a_scale_that_would_narrow_a_margin_or_is_no_number_is_refused(
    monkeypatch: pytest.MonkeyPatch, text: str
) -> None:
    monkeypatch.setenv(timescale.ENV_VAR, text)
    with pytest.raises(ValueError, match=timescale.ENV_VAR):
        timescale._read()


def test_scaled_multiplies_by_the_factor_read_at_import(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(timescale, "TIME_SCALE", 4.0)
    assert timescale.scaled(0.25) == 1.0
