"""What the fits become: a fitted spec, a DR preset centred on it and a host-side joint
calibration that carries the fitted zero offsets.

Joint zero offsets. A plant's offset acts in the servo's mounting (``hardware.plant``): a host on
the nominal calibration reads ``physical - offset``. The spec has no offset field and should not
get one: as in LeRobot's homing offsets and Dynamixel's calibration, the offset belongs to the
host's reading/command mapping, so that the policy sees joint angles in its model's frame. adapt
writes that mapping (``joint_calibration.yaml``: the user's or the nominal calibration, each
horn's units turned by its fitted offset, exactly as ``Plant.mounting`` turns the emulator's), and
every deploy of the adapted policy passes it (``--joint-calibration``). The fitted spec then holds
what an ArmSpec describes: the fitted servo figures and link lengths, and joint limits narrowed by
the offsets so that the firmware's compiled limits (built from readings) still contain them
(``offset_limits``). Its fingerprint is the adapted policy's; deploying it needs
``--spec fitted.yaml``.
"""

from __future__ import annotations

import copy
import math
from dataclasses import replace
from typing import Any

import numpy as np

from hardware.joint_calibration import ArmCalibration, nominal_calibration, with_joints
from hardware.protocols import get_protocol
from hardware.spec import ArmSpec
from sim2real.errors import ConfigError
from sim2real.sysid.apply import dr_centre, updated_spec
from sim2real.sysid.kinematics import KinematicFit
from sim2real.sysid.model import ServoFit

# Floors of the centred kinematic ranges (half-widths). The fit's covariance only sees pixel
# noise; a timing skew between readings and frames and the camera calibration and registration
# errors are biases it cannot see (sysid.kinematics). Issue 20's calibration targets (1 mm,
# 0.005 rad) are what the calibration is measured to reach, so the policy trains on at least
# that much residual error.
LINK_FLOOR_M = 0.001
OFFSET_FLOOR_RAD = 0.005
SIGMAS = 3.0  # a +-3 sigma range: the true value is inside it unless the fit is biased


# Limits are narrowed by this much beyond the offset, so the host's limits, rounded to whole
# servo units, never land one unit outside the firmware's compiled ones.
_LIMIT_MARGIN_RAD = 1e-4


def fitted_spec(spec: ArmSpec, servo: ServoFit, kin: KinematicFit) -> ArmSpec:
    """``spec`` with the fitted servo figures, the fitted link lengths (tool kept: a wrist
    marker cannot see it) and joint limits the offset calibration can hold
    (``offset_limits``)."""
    return offset_limits(kin.fitted_spec(updated_spec(spec, servo)), kin.joint_offset_rad)


def offset_limits(spec: ArmSpec, offsets_rad: np.ndarray) -> ArmSpec:
    """Joint limits (physical angles) reachable through the offset calibration.

    The firmware's compiled limits (``limits.h``, the emulator's) were built from the spec's
    limits in READING units, and firmware only lets a host tighten them. Through the offset
    calibration a physical angle p is the reading p - d, so the host may ask for p in
    [lo + d, hi + d]; the user's limits [lo, hi] still bound the physical joint. The fitted spec
    keeps the intersection (home and park clipped into it), so pushing its limits never asks
    the firmware for more than it was compiled with, and safety still holds the user's limits."""
    joints = []
    for j, d in zip(spec.joints, np.asarray(offsets_rad, dtype=float), strict=True):
        lo = math.ceil((max(j.lower_rad, j.lower_rad + d) + _LIMIT_MARGIN_RAD) * 1e4) / 1e4
        hi = math.floor((min(j.upper_rad, j.upper_rad + d) - _LIMIT_MARGIN_RAD) * 1e4) / 1e4
        if not lo < hi:
            raise ConfigError(
                f"joint {j.name}: fitted zero offset {d:+.4f} rad leaves no range inside its "
                f"limits [{j.lower_rad}, {j.upper_rad}] rad: re-seat the horn and calibrate again"
            )
        joints.append(
            replace(
                j,
                lower_rad=lo,
                upper_rad=hi,
                home_rad=min(max(j.home_rad, lo), hi),
                park_rad=min(max(j.park_rad, lo), hi),
            )
        )
    return replace(spec, joints=tuple(joints))


def centred_ranges(
    trained_ranges: dict[str, dict[str, list[float]]],
    servo: ServoFit,
    kin: KinematicFit,
    spec: ArmSpec,
    control_hz: float,
) -> dict[str, dict[str, list[float]]]:
    """The policy's own training ranges, with actuation and kinematics narrowed about the fit.

    - actuation: ``sysid.apply.dr_centre`` (+-20 % about the fitted dead band and speed, the
      fitted dead time in control steps); the action noise stays the training preset's;
    - dynamics: the fitted droop, +-20 % (a policy trained without it settles short on an arm
      that sags: the `hard` plant's 0.02 rad);
    - kinematics: link deltas and joint offsets about 0 (the fitted spec holds the links, the host
      calibration the offsets) with +-3 sigma half-widths, floored (see the floors' comment);
      the tool offset stays the training range (not observable from a wrist marker).
    Everything else (the other dynamics keys, sensing, visual, object) stays as the policy was
    trained."""
    out = copy.deepcopy(trained_ranges)
    for category, keys in dr_centre(servo, spec, control_hz).items():
        out[category] = {**out.get(category, {}), **keys}
    link_half = max(SIGMAS * float(np.max(kin.std[3:])), LINK_FLOOR_M)
    offset_half = max(SIGMAS * float(np.max(kin.std[:3])), OFFSET_FLOOR_RAD)
    kinematics = dict(out.get("kinematics", {}))
    kinematics["link_length_delta_m"] = [-round(link_half, 5), round(link_half, 5)]
    kinematics["joint_offset_rad"] = [-round(offset_half, 5), round(offset_half, 5)]
    out["kinematics"] = kinematics
    return out


def offset_calibration(
    spec: ArmSpec, protocol: str, offsets_rad: np.ndarray, base: ArmCalibration | None = None
) -> ArmCalibration:
    """``base`` (default: the nominal mapping) with each joint's horn turned by its fitted
    offset: a host on it reads ``old reading + offset``, the physical angle the fit found."""
    frame = get_protocol(protocol).unit_frame(spec)
    cal = base or nominal_calibration(spec, protocol, frame, arm_id="adapt")
    d = np.zeros(spec.n_actuators)
    d[: spec.n_joints] = np.asarray(offsets_rad, dtype=float)[: spec.n_joints]
    # units = offset_u + dir * scale * angle; reading r at units u becomes r + d when
    # offset_u' = offset_u - dir * scale * d (Plant.mounting's formula, from the host's side)
    shifted = cal.offset_units - cal.direction * cal.scale_units_per_rad * d
    return with_joints(cal, offsets_units=[float(v) for v in shifted])


def summary(servo: ServoFit, kin: KinematicFit) -> dict[str, Any]:
    return {
        "servo": {k: round(float(v), 6) for k, v in vars(servo).items()},
        "kinematics": kin.as_dict(),
    }
