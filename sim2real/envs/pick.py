"""Pick: grasp a small cube from the table and lift it at least 5 cm (gripper is a 4th action)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np

from sim2real import model as names
from sim2real.envs.base import Sensed, Task, register_task
from sim2real.observation import ObsField

if TYPE_CHECKING:
    from sim2real.envs.base import Arm3Env

LIFT_M = 0.07  # goal above the start pose; with the 2 cm success ball, success ⇒ lifted ≥ 5 cm
REACH_WEIGHT_PER_M = 2.0  # approach term: -2·|ee − cube|
GRASP_BONUS = 0.5  # per step with both fingers on the cube: more than the lift term's first 5 cm


@register_task
class PickTask(Task):
    name = "pick"
    scene = "pick"
    uses_gripper = True
    success_threshold_m = 0.02

    def __init__(self) -> None:
        self.goal_m = np.zeros(3)
        self._cube_qadr = -1
        self._finger_geoms: frozenset[int] = frozenset()

    def reset(self, env: Arm3Env, rng: np.random.Generator) -> None:
        m = env.model
        if self._cube_qadr < 0:
            self._cube_qadr = int(m.joint(names.CUBE_JOINT).qposadr[0])
            self._cube_body = m.body(names.CUBE_BODY).id
            self._cube_geom = m.geom(names.CUBE_GEOM).id
            self._finger_geoms = frozenset(m.geom(g).id for g in names.FINGER_GEOMS)
        radius = rng.uniform(0.12, 0.19)
        angle = rng.uniform(-0.5, 0.5)
        xy = radius * np.array([np.cos(angle), np.sin(angle)])
        xy = xy + env.dr_params.get("object", {}).get("init_xy_offset_m", np.zeros(2))
        half = float(m.geom_size[env.ids.cube_geom][2])
        yaw = rng.uniform(-np.pi / 4, np.pi / 4)
        q = env.data.qpos
        a = self._cube_qadr
        q[a : a + 3] = (xy[0], xy[1], half)
        q[a + 3 : a + 7] = (np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2))
        self.goal_m = np.array([xy[0], xy[1], half + LIFT_M])
        env.data.mocap_pos[0] = self.goal_m
        mujoco.mj_forward(m, env.data)

    def cube_position(self, env: Arm3Env) -> np.ndarray:
        return env.data.xpos[self._cube_body]

    def true_points(self, env: Arm3Env) -> np.ndarray:
        return self.cube_position(env)[None]

    def goals(self, env: Arm3Env, sensed: Sensed) -> tuple[np.ndarray, np.ndarray]:
        return sensed.points_m[0], self.goal_m

    def true_goals(self, env: Arm3Env) -> tuple[np.ndarray, np.ndarray]:
        return self.cube_position(env), self.goal_m

    def extra_fields(self) -> tuple[ObsField, ...]:
        return (
            ObsField("cube_pos", 3, "m", "cube position estimate, base frame"),
            ObsField("cube_delta", 3, "m", "cube minus end effector"),
        )

    def extra_readings(self, env: Arm3Env, sensed: Sensed) -> dict[str, np.ndarray]:
        cube = sensed.points_m[0]
        return {"cube_pos": cube, "cube_delta": cube - sensed.ee_m}

    def is_grasped(self, env: Arm3Env) -> bool:
        """Both fingers touch the cube (from MuJoCo's contact list)."""
        d = env.data
        touching: set[int] = set()
        cube, fingers = self._cube_geom, self._finger_geoms
        for i in range(d.ncon):
            c = d.contact[i]
            g1, g2 = int(c.geom1), int(c.geom2)
            if g1 == cube and g2 in fingers:
                touching.add(g2)
            elif g2 == cube and g1 in fingers:
                touching.add(g1)
        return len(touching) == len(fingers)

    def shaping(self, env: Arm3Env) -> float:
        """Staged, as robosuite's Lift: approach the cube, then hold it. Without the grasp term a
        dense policy learns to hover by the cube (the lift term alone pays only once it rises)."""
        reach = -REACH_WEIGHT_PER_M * float(
            np.linalg.norm(env.ee_position() - self.cube_position(env))
        )
        return reach + (GRASP_BONUS if self.is_grasped(env) else 0.0)
