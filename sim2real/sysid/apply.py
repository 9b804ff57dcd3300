"""Write the fit back: an updated ArmSpec and a DR preset centred on what was measured."""

from __future__ import annotations

from pathlib import Path

import yaml

from hardware.spec import ArmSpec
from sim2real.sysid.model import ServoFit


def updated_spec(spec: ArmSpec, fit: ServoFit) -> ArmSpec:
    return spec.with_servo(
        time_constant_s=round(float(fit.time_constant_s), 5),
        max_speed_rad_s=round(float(fit.max_speed_rad_s), 4),
        deadband_rad=round(float(fit.deadband_rad), 5),
        latency_s=round(float(fit.latency_s), 4),
    )


def dr_centre(
    fit: ServoFit, spec: ArmSpec, control_hz: float = 20.0
) -> dict[str, dict[str, list[float]]]:
    """The actuation ranges of a preset, ±20 % around the fit (latency in whole control steps).

    ``max_speed_scale`` is relative to the *updated* spec, so it is centred on 1."""
    latency_steps = fit.latency_s * control_hz
    return {
        "actuation": {
            "latency_steps": [float(round(latency_steps))] * 2,
            "max_speed_scale": [0.8, 1.2],
            "deadband_rad": [
                round(float(0.8 * fit.deadband_rad), 5),
                round(float(1.2 * fit.deadband_rad), 5),
            ],
            "quantisation_rad": [float(spec.servo.resolution_rad)] * 2,
        }
    }


def write_outputs(
    out_spec: Path, spec: ArmSpec, fit: ServoFit, rms_rad: float, sources: list[str]
) -> tuple[Path, Path]:
    """Both files atomically; the preset sits beside the spec as ``<stem>.dr.yaml``."""
    from hardware.atomic import atomic_write_text

    new = updated_spec(spec, fit)
    preset_text = yaml.safe_dump(dr_centre(fit, new), sort_keys=False)  # fails before any write
    header = (
        f"ArmSpec {new.name}: servo model fitted by `sim2real sysid` to {', '.join(sources)}\n"
        f"fit RMS reading error {rms_rad:.5f} rad; droop {fit.droop_rad:+.4f} rad"
    )
    preset = out_spec.with_name(out_spec.stem + ".dr.yaml")
    text = "# DR preset centred on the sysid fit (sim2real sysid); use with --dr " + str(preset)
    new.to_yaml(out_spec, header=header)
    atomic_write_text(preset, text + "\n" + preset_text)
    return out_spec, preset
