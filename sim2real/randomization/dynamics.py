"""Dynamics DR: link masses, joint damping, friction loss, armature, servo gain and droop.

Droop is the steady sag a hobby servo's proportional loop leaves under the tool's weight beyond
what MuJoCo's gravity on the position actuator gives: the pitch joints settle ``droop`` below
their target, as the emulator's servos do (``hardware.servo_model``: target + droop, negative on
the y-axis joints). On a position actuator that is a constant bias ``kp * droop``: the force
``kp * (ctrl - q) + kp * droop`` is the servo driving to ``ctrl + droop``, with no per-step
cost.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from sim2real.randomization.base import (
    DirectKey,
    ModelIds,
    ModelSnapshot,
    Params,
    PlanCache,
    as_index,
    draw_keys,
)
from sim2real.randomization.config import Range


def sample(rng: np.random.Generator, ranges: Mapping[str, Range], ids: ModelIds) -> Params:
    """Independent draws per link / dof / actuator: no two servos or links are alike."""
    return draw_keys(direct_keys(ids), rng, ranges)


def direct_keys(ids: ModelIds) -> list[DirectKey]:
    """Each draw, in order, with its size: per link, per dof, per servo actuator."""
    n_b, n_d, n_a = len(ids.arm_bodies), len(ids.arm_dofs), len(ids.servo_actuators)
    return [
        ("link_mass_scale", n_b, None),
        ("joint_damping_scale", n_d, None),
        ("joint_frictionloss_nm", n_d, None),
        ("armature_scale", n_d, None),
        ("actuator_gain_scale", n_a, None),
        # last, so presets without droop draw exactly as before it existed
        ("actuator_droop_rad", None, float),
    ]


def droop_direction(model: mujoco.MjModel, ids: ModelIds) -> np.ndarray:
    """Per servo actuator: -1 on a pitch (y-axis hinge) joint, 0 elsewhere (a slide, such as
    the Kuka gripper's, does not sag), as the emulator's ``ServoParams.from_spec`` sags them."""
    joints = model.dof_jntid[ids.arm_dofs]
    hinge = model.jnt_type[joints] == mujoco.mjtJoint.mjJNT_HINGE
    return -((np.abs(model.jnt_axis[joints, 1]) > 0.5) & hinge).astype(float)


def apply_reference(
    model: mujoco.MjModel, nominal: ModelSnapshot, ids: ModelIds, params: Params
) -> None:
    """Write scaled nominal values; never compounds, so repeated episodes do not drift."""
    b, d, a = ids.arm_bodies, ids.arm_dofs, ids.servo_actuators
    mass = np.asarray(params["link_mass_scale"])
    model.body_mass[b] = nominal["body_mass"][b] * mass
    model.body_inertia[b] = nominal["body_inertia"][b] * mass[:, None]
    model.dof_damping[d] = nominal["dof_damping"][d] * params["joint_damping_scale"]
    model.dof_frictionloss[d] = params["joint_frictionloss_nm"]
    model.dof_armature[d] = nominal["dof_armature"][d] * params["armature_scale"]
    gain = np.asarray(params["actuator_gain_scale"])
    # A position servo is gain kp and bias -kp*q - kv*qdot: scale both to keep it a servo.
    model.actuator_gainprm[a, 0] = nominal["actuator_gainprm"][a, 0] * gain
    model.actuator_biasprm[a, 1] = nominal["actuator_biasprm"][a, 1] * gain
    model.actuator_biasprm[a, 2] = nominal["actuator_biasprm"][a, 2] * gain
    droop_rad = droop_direction(model, ids) * float(params["actuator_droop_rad"])
    model.actuator_biasprm[a, 0] = (
        nominal["actuator_biasprm"][a, 0] + model.actuator_gainprm[a, 0] * droop_rad
    )


@dataclass(frozen=True)
class _Plan:
    """``apply_reference``'s ids, nominal rows and model arrays, resolved once per model."""

    b: Any  # slice or index array (``as_index``)
    d: Any
    a: Any
    mass: np.ndarray
    inertia: np.ndarray
    damping: np.ndarray
    armature: np.ndarray
    gain: np.ndarray  # (n_a,) gainprm[:, 0]
    bias: np.ndarray  # (n_a, 2) biasprm[:, 1:3]
    bias0: np.ndarray  # (n_a,) biasprm[:, 0]
    droop: np.ndarray  # (n_a,) droop_direction
    body_mass: np.ndarray  # the model's own arrays (views of its buffers)
    body_inertia: np.ndarray
    dof_damping: np.ndarray
    dof_frictionloss: np.ndarray
    dof_armature: np.ndarray
    gainprm: np.ndarray
    biasprm: np.ndarray

    @classmethod
    def of(cls, model: mujoco.MjModel, nominal: ModelSnapshot, ids: ModelIds) -> _Plan:
        b, d, a = ids.arm_bodies, ids.arm_dofs, ids.servo_actuators
        return cls(
            b=as_index(b),
            d=as_index(d),
            a=as_index(a),
            mass=nominal["body_mass"][b],
            inertia=nominal["body_inertia"][b],
            damping=nominal["dof_damping"][d],
            armature=nominal["dof_armature"][d],
            gain=nominal["actuator_gainprm"][a, 0],
            bias=nominal["actuator_biasprm"][a, 1:3],
            bias0=nominal["actuator_biasprm"][a, 0],
            droop=droop_direction(model, ids),
            body_mass=model.body_mass,
            body_inertia=model.body_inertia,
            dof_damping=model.dof_damping,
            dof_frictionloss=model.dof_frictionloss,
            dof_armature=model.dof_armature,
            gainprm=model.actuator_gainprm,
            biasprm=model.actuator_biasprm,
        )


_PLANS = PlanCache(_Plan.of)


def apply(model: mujoco.MjModel, nominal: ModelSnapshot, ids: ModelIds, params: Params) -> None:
    """``apply_reference``'s products on the same values (the same bits), written through a
    plan resolved once per model (``tests/sim2real/randomization/test_appliers.py``)."""
    p = _PLANS.get(model, nominal, ids)
    mass = np.asarray(params["link_mass_scale"])
    p.body_mass[p.b] = p.mass * mass
    p.body_inertia[p.b] = p.inertia * mass[:, None]
    p.dof_damping[p.d] = p.damping * params["joint_damping_scale"]
    p.dof_frictionloss[p.d] = params["joint_frictionloss_nm"]
    p.dof_armature[p.d] = p.armature * params["armature_scale"]
    gain = np.asarray(params["actuator_gain_scale"])
    # A position servo is gain kp and bias -kp*q - kv*qdot: scale both to keep it a servo.
    p.gainprm[p.a, 0] = p.gain * gain
    p.biasprm[p.a, 1:3] = p.bias * gain[:, None]
    p.biasprm[p.a, 0] = p.bias0 + p.gainprm[p.a, 0] * (
        p.droop * float(params["actuator_droop_rad"])
    )
