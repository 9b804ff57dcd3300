"""Pick: grasp a small cube from the table and lift it at least 5 cm (gripper is a 4th action)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np

from sim2real import model as names
from sim2real.envs.base import START_DEFAULT, START_HELD, Sensed, Task, register_task
from sim2real.errors import ConfigError
from sim2real.observation import ObsField

if TYPE_CHECKING:
    from sim2real.envs.base import Arm3Env

LIFT_M = 0.07  # goal above the start pose; with the 2 cm success ball, success ⇒ lifted ≥ 5 cm
REACH_WEIGHT_PER_M = 2.0  # approach term: -2·|ee − cube|
GRASP_BONUS = 0.5  # per step with both fingers on the cube: more than the goal term's first 5 cm
LIFT_WEIGHT_PER_M = 10.0  # per step while grasped: +10·(cube height gained), at most +0.7
# Held start: the gripper closes on the cube by a ramp of its position command over this many
# physics steps (stepping the command to "closed" at once slams the fingers into a cube that is
# only held by friction and can throw it), then holds for SETTLE steps so the contacts are real.
HELD_RAMP_STEPS = 20
HELD_SETTLE_STEPS = 20
HELD_RAMP_SQUEEZE_M = 0.004  # finger command below the cube face at the ramp's end (force-capped)
BLIND_CAP_S = 2.0  # the cube_blind_s reading saturates here: longer is "not seen this episode"


def cube_readings(ee_m: np.ndarray, cube_m: np.ndarray, blind_s: float) -> dict[str, np.ndarray]:
    """The pick-specific readings, from the env's sensor models and from the deploy loop's
    cube tracker alike: the cube estimate (held at its last sighting while hidden), its offset
    from the tool and how long it has been blind."""
    return {
        "cube_pos": cube_m,
        "cube_delta": cube_m - ee_m,
        "cube_blind_s": np.array([min(max(float(blind_s), 0.0), BLIND_CAP_S)]),
    }


def lift_goal(cube_rest_m: np.ndarray) -> np.ndarray:
    """The lift point above where the cube rests (success: the cube within 2 cm of it)."""
    return np.asarray(cube_rest_m, dtype=float) + (0.0, 0.0, LIFT_M)


@register_task
class PickTask(Task):
    name = "pick"
    scene = "pick"
    uses_gripper = True
    success_threshold_m = 0.02
    start_modes = (START_DEFAULT, START_HELD)
    occludable = True  # the fingers hide the cube's markers during a grasp
    command_fields = True

    def __init__(self) -> None:
        self.goal_m = np.zeros(3)
        self.rest_z_m = 0.0  # cube centre height resting on the table
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
        self.rest_z_m = half
        self.goal_m = lift_goal(np.array([xy[0], xy[1], half]))
        env.data.mocap_pos[0] = self.goal_m
        mujoco.mj_forward(m, env.data)

    def held_start(
        self, env: Arm3Env, rng: np.random.Generator, height_m: float | None
    ) -> np.ndarray:
        """The cube in the closed gripper, ``height_m`` (default: uniform in [0, LIFT_M]) above
        where ``reset`` put it, with real contacts: what a scripted grasp and lift (the arm's own
        IK, as ``tests/sim2real/test_tasks.py`` drives it) leaves, without its 40-step cost.

        The arm is posed by IK with the tool at the cube centre, the fingers touch the cube's
        faces and the cube is turned square to them; then the gripper command ramps closed and
        physics settles. A height out of reach falls back to the table (h = 0)."""
        if height_m is None:
            height_m = float(rng.uniform(0.0, LIFT_M))
        if not 0.0 <= height_m <= LIFT_M:
            raise ConfigError(f"held_height_m {height_m} not in [0, {LIFT_M}]")
        m, d, spec = env.model, env.data, env.spec_arm
        grip = spec.gripper
        if grip is None:  # pragma: no cover - the decoder already refuses a gripperless spec
            raise ConfigError(f"spec {spec.name!r} has no gripper for a held start")
        rest = self.cube_position(env).copy()
        q = spec.inverse_kinematics(rest + (0.0, 0.0, height_m))
        if q is None:
            q = spec.inverse_kinematics(rest)
        if q is None:
            raise ConfigError(f"held start: cube at {np.round(rest, 3).tolist()} m is out of reach")
        n = spec.n_joints
        targets = spec.actuator_home_rad.copy()
        targets[:n] = q
        targets[n] = grip.closed_rad
        half_w = float(m.geom_size[self._cube_geom][0])
        env.twin.set_pose(d, q, None)
        d.qpos[env.twin.finger_qadr] = half_w  # finger inner faces on the cube's faces
        mujoco.mj_kinematics(m, d)
        a = self._cube_qadr
        d.qpos[a : a + 3] = env.ee_position()
        mujoco.mju_mat2Quat(d.qpos[a + 3 : a + 7], d.geom_xmat[min(self._finger_geoms)])
        d.qvel[:] = 0.0
        env.twin.write_ctrl(d, q, None)
        for k in range(1, HELD_RAMP_STEPS + 1):
            d.ctrl[n] = max(half_w - k / HELD_RAMP_STEPS * HELD_RAMP_SQUEEZE_M, 0.0)
            mujoco.mj_step(m, d)
        env.twin.write_ctrl(d, q, grip.closed_rad)
        mujoco.mj_step(m, d, nstep=HELD_SETTLE_STEPS)
        d.time = 0.0
        return targets

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
            ObsField(
                "cube_blind_s", 1, "s", f"time since the cube was last seen (cap {BLIND_CAP_S})"
            ),
        )

    def extra_readings(self, env: Arm3Env, sensed: Sensed) -> dict[str, np.ndarray]:
        return cube_readings(sensed.ee_m, sensed.points_m[0], float(sensed.blind_s[0]))

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

    def lift_m(self, env: Arm3Env) -> float:
        """Cube height gained above its resting height, clipped to [0, LIFT_M]."""
        return min(max(float(self.cube_position(env)[2]) - self.rest_z_m, 0.0), LIFT_M)

    def shaping(self, env: Arm3Env) -> float:
        """Staged, as robosuite's Lift: approach the cube, hold it, lift it.

        Without the grasp term a dense policy learns to hover by the cube. With it alone, a
        policy learned to close on the cube and stay on the table: the goal term pays only
        5/m of height, so the first centimetres (+0.05/cm) are little next to the +0.5 grasp
        bonus that a fumble loses. The lift term pays +10/m more while grasped (at most +0.7 at the
        lift goal): holding the cube 5 cm up, the shaping pays 1.0 per step against 0.5 on the
        table, and a cube knocked upwards without a grasp earns nothing from it."""
        reach = -REACH_WEIGHT_PER_M * float(
            np.linalg.norm(env.ee_position() - self.cube_position(env))
        )
        if not self.is_grasped(env):
            return reach
        return reach + GRASP_BONUS + LIFT_WEIGHT_PER_M * self.lift_m(env)
