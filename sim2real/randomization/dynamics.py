"""Dynamics DR: link masses, joint damping, friction loss, armature, servo gain."""

from __future__ import annotations

from collections.abc import Mapping

import mujoco
import numpy as np

from sim2real.randomization.base import ModelIds, ModelSnapshot, Params
from sim2real.randomization.config import Range


def sample(rng: np.random.Generator, ranges: Mapping[str, Range], ids: ModelIds) -> Params:
    """Independent draws per link / dof / actuator: no two servos or links are alike."""
    n_b, n_d, n_a = len(ids.arm_bodies), len(ids.arm_dofs), len(ids.servo_actuators)
    return {
        "link_mass_scale": ranges["link_mass_scale"].sample(rng, n_b),
        "joint_damping_scale": ranges["joint_damping_scale"].sample(rng, n_d),
        "joint_frictionloss_nm": ranges["joint_frictionloss_nm"].sample(rng, n_d),
        "armature_scale": ranges["armature_scale"].sample(rng, n_d),
        "actuator_gain_scale": ranges["actuator_gain_scale"].sample(rng, n_a),
    }


def apply(model: mujoco.MjModel, nominal: ModelSnapshot, ids: ModelIds, params: Params) -> None:
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
