"""Write the fit back: an updated ArmSpec and a DR preset centred on what was measured."""

from __future__ import annotations

import math
from pathlib import Path

import yaml

from hardware.spec import ArmSpec
from sim2real.errors import ConfigError
from sim2real.sysid.model import ServoFit


def updated_spec(spec: ArmSpec, fit: ServoFit) -> ArmSpec:
    return spec.with_servo(
        time_constant_s=round(float(fit.time_constant_s), 5),
        max_speed_rad_s=round(float(fit.max_speed_rad_s), 4),
        deadband_rad=round(float(fit.deadband_rad), 5),
        latency_s=round(float(fit.latency_s), 4),
    )


def latency_steps_range(latency_s: float, control_hz: float) -> list[float]:
    """DR range of ``actuation.latency_steps`` for a fitted dead time, at the policy's rate.

    The env rounds a uniform sample to whole control steps, so the range spans at least one step
    centred on ``latency_s * control_hz`` (the rounded samples then average to the fractional
    value: 40 ms at 20 Hz is 0.8 steps, one step 80 % of the time) and ±20 % beyond that."""
    if not (math.isfinite(control_hz) and control_hz > 0):
        raise ConfigError(f"control_hz must be finite and > 0, got {control_hz!r}")
    steps = float(latency_s) * control_hz
    low = max(0.0, min(0.8 * steps, steps - 0.5))
    high = max(1.2 * steps, steps + 0.5)
    return [round(low, 3), round(high, 3)]


def dr_centre(
    fit: ServoFit, spec: ArmSpec, control_hz: float = 20.0
) -> dict[str, dict[str, list[float]]]:
    """The actuation ranges of a preset, ±20 % around the fit (latency in control steps at
    ``control_hz``, the policy's rate), and the fitted droop's, ±20 %, in ``dynamics`` (the
    sim's servo sag, ``randomization.dynamics``; 0 when the fit had none).

    ``max_speed_scale`` is relative to the *updated* spec, so it is centred on 1."""
    droop_rad = max(0.0, -float(fit.droop_rad))  # the fit's sag is signed, downwards
    return {
        "dynamics": {
            "actuator_droop_rad": [round(0.8 * droop_rad, 5), round(1.2 * droop_rad, 5)],
        },
        "actuation": {
            "latency_steps": latency_steps_range(fit.latency_s, control_hz),
            "max_speed_scale": [0.8, 1.2],
            "deadband_rad": [
                round(float(0.8 * fit.deadband_rad), 5),
                round(float(1.2 * fit.deadband_rad), 5),
            ],
            "quantisation_rad": [float(spec.servo.resolution_rad)] * 2,
        },
    }


def write_outputs(
    out_spec: Path,
    spec: ArmSpec,
    fit: ServoFit,
    rms_rad: float,
    sources: list[str],
    control_hz: float = 20.0,
) -> tuple[Path, Path]:
    """Both files atomically; the preset sits beside the spec as ``<stem>.dr.yaml``."""
    from hardware.atomic import atomic_write_text

    new = updated_spec(spec, fit)
    # built before any write, so a bad control_hz leaves nothing half-written
    preset_text = yaml.safe_dump(dr_centre(fit, new, control_hz), sort_keys=False)
    header = (
        f"ArmSpec {new.name}: servo model fitted by `sim2real sysid` to {', '.join(sources)}\n"
        f"fit RMS reading error {rms_rad:.5f} rad; droop {fit.droop_rad:+.4f} rad; "
        f"latency {fit.latency_s * 1000:.1f} ms ({fit.latency_s * control_hz:.2f} steps at "
        f"{control_hz:g} Hz)"
    )
    preset = out_spec.with_name(out_spec.stem + ".dr.yaml")
    text = "# DR preset centred on the sysid fit (sim2real sysid); use with --dr " + str(preset)
    new.to_yaml(out_spec, header=header)
    atomic_write_text(preset, text + "\n" + preset_text)
    return out_spec, preset
