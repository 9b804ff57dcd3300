"""The shared DR presets on robosuite models: same keys, same samplers, robosuite's modders.

Sampling reuses the five shared ``sample`` functions unchanged (same keys, same units, same draw
order), so one seed gives the same parameter stream on both backends. Applying them maps each key
onto what a torque-controlled robosuite arm has (docs/robosuite.md has the table and the reasons):

- ``dynamics`` → robosuite's ``DynamicsModder`` (link mass and inertia, joint damping, friction
  loss, armature); ``actuator_gain_scale`` scales the arm's torque motors directly (the modders
  have no actuator setter). ``joint_frictionloss_nm`` is *added* to the robot's own friction loss:
  the native arm's nominal is 0, so it means "extra friction" on both backends.
  ``actuator_droop_rad`` (a hobby servo's sag) is sampled but ignored: torque motors have no
  position loop to sag.
- ``visual`` → ``LightingModder`` (diffuse, position), ``CameraModder`` (position, fovy) and a
  colour jitter of each geom's rendered colour. robosuite's ``TextureModder`` cannot be used: on
  mujoco 3 it fails on construction (``MjModel`` has no ``tex_rgb``), so colours go through geom
  rgba here, starting from the material colour a geom actually shows.
- ``object`` → the shared object layer on the task object's collision geom, plus its visual geoms
  so pixels agree with physics.
- ``actuation`` → ``RobosuiteActuation`` (latency, command noise, speed scale); the hobby-servo
  keys ``deadband_rad`` and ``quantisation_rad`` are sampled but ignored.
- ``sensing`` → the shared ``SensorModel`` (in the env).

Everything written lives in ``TOUCHED_FIELDS``, so the shared ``ModelSnapshot`` restores it bit for
bit before each episode's parameters are applied.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from sim2real.errors import ConfigError
from sim2real.randomization import CATEGORIES, ModelIds, ModelSnapshot, Params
from sim2real.randomization import object as object_dr
from sim2real.randomization.base import shown_rgba
from sim2real.randomization.config import DRConfig
from sim2real.randomization.robosuite_compat import import_robosuite

import_robosuite()
from robosuite.utils.mjmod import (  # noqa: E402  (after the quiet import)
    CameraModder,
    DynamicsModder,
    LightingModder,
)

# MuJoCo draws a geom in its material's colour while the geom rgba is at this default.
# How far the hand moves per radian at the shoulder of a Panda-sized arm: turns the rad-valued
# command noise into metres for Cartesian (OSC) commands.
LEVER_M = 0.5
# Physical units of one command dimension → its size per radian of "command noise".
UNIT_PER_RAD: dict[str, float] = {"rad": 1.0, "m": LEVER_M, "N*m": 0.0}
IGNORED_KEYS: dict[str, tuple[str, ...]] = {
    "dynamics": ("actuator_droop_rad",),
    "actuation": ("deadband_rad", "quantisation_rad"),
}


@dataclass(frozen=True)
class RobosuiteTargets:
    """What DR touches in one robosuite model: ids for the shared samplers, names for modders."""

    ids: ModelIds
    link_bodies: tuple[str, ...]  # one per arm joint: the body that joint moves
    arm_joints: tuple[str, ...]
    cameras: tuple[str, ...]
    lights: tuple[str | None, ...]
    object_visual_geoms: np.ndarray  # visual geoms of the task object (scaled with it)

    @classmethod
    def from_model(
        cls,
        model: mujoco.MjModel,
        arm_joints: Sequence[str],
        arm_actuators: Sequence[str],
        colour_geoms: Sequence[str],
        object_geom: str | None,
        object_body: str | None,
        object_visual_geoms: Sequence[str] = (),
    ) -> RobosuiteTargets:
        joint_ids = [model.joint(j).id for j in arm_joints]
        bodies = np.array([model.jnt_bodyid[j] for j in joint_ids], dtype=np.intp)
        lights = tuple(model.light(i).name or None for i in range(model.nlight))
        if len(set(lights)) != len(lights):
            raise ConfigError(
                f"robosuite scene has duplicate light names {lights}; cannot randomise"
            )
        ids = ModelIds(
            arm_bodies=bodies,
            arm_dofs=np.array([model.jnt_dofadr[j] for j in joint_ids], dtype=np.intp),
            servo_actuators=np.array([model.actuator(a).id for a in arm_actuators], dtype=np.intp),
            colour_geoms=np.array([model.geom(g).id for g in colour_geoms], dtype=np.intp),
            cube_geom=model.geom(object_geom).id if object_geom else -1,
            cube_body=model.body(object_body).id if object_body else -1,
            cameras=np.arange(model.ncam, dtype=np.intp),
            lights=np.arange(model.nlight, dtype=np.intp),
        )
        return cls(
            ids=ids,
            link_bodies=tuple(model.body(int(b)).name for b in bodies),
            arm_joints=tuple(arm_joints),
            cameras=tuple(model.camera(i).name for i in range(model.ncam)),
            lights=lights,
            object_visual_geoms=np.array(
                [model.geom(g).id for g in object_visual_geoms], dtype=np.intp
            ),
        )


class RobosuiteRandomizer:
    """Samples a preset per episode with the shared samplers; applies it through the modders."""

    def __init__(self, sim: Any, targets: RobosuiteTargets, config: DRConfig) -> None:
        self.sim = sim
        self.model: mujoco.MjModel = sim.model._model
        self.targets = targets
        self.config = config
        self.nominal = ModelSnapshot(self.model)
        self._nominal_shown_rgba = shown_rgba(self.model, targets.ids.colour_geoms)
        # Modders get a private RandomState: we never call their randomize() (DynamicsModder's
        # draws from the global np.random), only their setters with our sampled values.
        rs = np.random.RandomState(0)
        self.dynamics = DynamicsModder(sim, random_state=rs, joint_names=list(targets.arm_joints))
        self.cameras = CameraModder(sim, random_state=rs, camera_names=list(targets.cameras))
        self.lights = LightingModder(sim, random_state=rs, light_names=list(targets.lights))

    def sample(self, rng: np.random.Generator) -> dict[str, Params]:
        """Every category in the shared fixed order, so a seed fixes the whole episode."""
        ids = self.targets.ids
        return {name: cat.sample(rng, self.config[name], ids) for name, cat in CATEGORIES.items()}

    def apply(self, params: Mapping[str, Params], visual: bool = True) -> None:
        """Restore nominal, then write this episode's model parameters (never compounding)."""
        self.nominal.restore()
        if not self.config.is_neutral("dynamics"):
            self._apply_dynamics(params["dynamics"])
        if visual and not self.config.is_neutral("visual"):
            self._apply_visual(params["visual"])
        if not self.config.is_neutral("object") and self.targets.ids.cube_geom >= 0:
            self._apply_object(params["object"])

    def restore_nominal(self) -> None:
        self.nominal.restore()

    def _apply_dynamics(self, p: Params) -> None:
        t, nom, dm = self.targets, self.nominal, self.dynamics
        mass = np.asarray(p["link_mass_scale"])
        for i, (name, b) in enumerate(zip(t.link_bodies, t.ids.arm_bodies, strict=True)):
            dm.mod_mass(name, nom["body_mass"][b] * mass[i])
            dm.mod_inertia(name, nom["body_inertia"][b] * mass[i])
        for i, (name, d) in enumerate(zip(t.arm_joints, t.ids.arm_dofs, strict=True)):
            dm.mod_damping(name, nom["dof_damping"][d] * p["joint_damping_scale"][i])
            dm.mod_frictionloss(name, nom["dof_frictionloss"][d] + p["joint_frictionloss_nm"][i])
            dm.mod_armature(name, nom["dof_armature"][d] * p["armature_scale"][i])
        # Torque motors: force = gain · ctrl. Position-type actuators (bias -kp·q - kv·qdot) get
        # kp and kv scaled too, as on the native arm, so they stay servos.
        a = t.ids.servo_actuators
        gain = np.asarray(p["actuator_gain_scale"])
        m = self.model
        m.actuator_gainprm[a, 0] = nom["actuator_gainprm"][a, 0] * gain
        m.actuator_biasprm[a, 1] = nom["actuator_biasprm"][a, 1] * gain
        m.actuator_biasprm[a, 2] = nom["actuator_biasprm"][a, 2] * gain

    def _apply_visual(self, p: Params) -> None:
        t, nom = self.targets, self.nominal
        light_ids = t.ids.lights
        scale = np.reshape(p["light_diffuse_scale"], (-1, 1))
        for i, (name, lid) in enumerate(zip(t.lights, light_ids, strict=True)):
            self.lights.set_diffuse(name, np.clip(nom["light_diffuse"][lid] * scale[i], 0.0, 1.0))
            self.lights.set_pos(name, nom["light_pos"][lid] + p["light_pos_offset_m"][i])
        for i, (name, cid) in enumerate(zip(t.cameras, t.ids.cameras, strict=True)):
            self.cameras.set_pos(name, nom["cam_pos"][cid] + p["camera_pos_offset_m"][i])
            self.cameras.set_fovy(name, nom["cam_fovy"][cid] + p["camera_fovy_offset_deg"][i])
        rgba = self._nominal_shown_rgba.copy()
        rgba[:, :3] = np.clip(rgba[:, :3] + p["rgba_offset"], 0.0, 1.0)
        self.model.geom_rgba[t.ids.colour_geoms] = rgba

    def _apply_object(self, p: Params) -> None:
        m, nom, vis = self.model, self.nominal, self.targets.object_visual_geoms
        object_dr.apply(m, nom, self.targets.ids, p)
        s = p["size_scale"]
        m.geom_size[vis] = nom["geom_size"][vis] * s
        m.geom_rbound[vis] = nom["geom_rbound"][vis] * s
        m.geom_aabb[vis] = nom["geom_aabb"][vis] * s


class RobosuiteActuation:
    """What happens to a normalised command between the policy and robosuite's controller.

    Per control step: noise on the arm dimensions (the preset's σ in rad, turned into each
    dimension's unit and normalised by the controller's scale) → transport latency (whole command,
    gripper included) → speed scale (the arm moves ``max_speed_scale`` of the commanded step).
    """

    def __init__(self, idle_action: np.ndarray, arm_dims: int, noise_per_rad: np.ndarray) -> None:
        self._idle = np.asarray(idle_action, dtype=float).copy()
        self._arm = arm_dims
        self._noise_per_rad = np.asarray(noise_per_rad, dtype=float)  # (arm_dims,)
        if self._noise_per_rad.shape != (arm_dims,):
            raise ConfigError(
                f"noise_per_rad has shape {self._noise_per_rad.shape}, expected ({arm_dims},)"
            )
        self.latency_steps = 0
        self._sigma = np.zeros(arm_dims)
        self.speed_scale = 1.0
        self._queue: deque[np.ndarray] = deque()

    def configure(self, params: Params) -> None:
        self.latency_steps = int(params["latency_steps"])
        self._sigma = float(params["action_noise_rad"]) * self._noise_per_rad
        self.speed_scale = float(params["max_speed_scale"])

    def reset(self) -> None:
        self._queue = deque([self._idle.copy() for _ in range(self.latency_steps)])

    def __call__(self, action: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        cmd = np.array(action, dtype=float)
        arm = cmd[: self._arm]
        if self._sigma.any():
            arm += rng.normal(0.0, 1.0, self._arm) * self._sigma
        if self.latency_steps:
            self._queue.append(cmd)
            cmd = self._queue.popleft()
        out = cmd.copy()
        out[: self._arm] *= self.speed_scale
        np.clip(out, -1.0, 1.0, out=out)
        return out


def noise_per_rad(units: Sequence[str], scale_per_unit: np.ndarray) -> np.ndarray:
    """Normalised-action σ per radian of command noise, per arm dimension.

    ``scale_per_unit`` is the controller's physical output per normalised unit (m, rad or N·m).
    """
    per_rad = np.array([UNIT_PER_RAD[u] for u in units])
    return per_rad / np.asarray(scale_per_unit, dtype=float)


__all__ = [
    "IGNORED_KEYS",
    "LEVER_M",
    "UNIT_PER_RAD",
    "RobosuiteActuation",
    "RobosuiteRandomizer",
    "RobosuiteTargets",
    "noise_per_rad",
    "shown_rgba",
]
