"""Pick: grasp a small cube from the table and lift it at least 5 cm (gripper is a 4th action)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np

from sim2real import model as names
from sim2real.envs import fused
from sim2real.envs.base import START_DEFAULT, START_HELD, Task, register_task
from sim2real.envs.contract import DeployContract, Outcome, Percept, View, need
from sim2real.errors import ConfigError
from sim2real.observation import ObsField

if TYPE_CHECKING:
    from hardware.spec import ArmSpec
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
# The tool (between the fingertips) is this close to the cube's centre when both fingers hold it:
# the cube is 21-29 mm wide and the fingers close on its faces.
GRASP_NEAR_M = 0.02


def cube_readings(ee_m: np.ndarray, cube_m: np.ndarray, blind_s: float) -> dict[str, np.ndarray]:
    """The pick-specific readings, from the env's sensor models and from the deploy loop's
    cube tracker alike: the cube estimate (held at its last sighting while hidden), its offset
    from the tool and how long it has been blind."""
    return {
        "cube_pos": cube_m,
        "cube_delta": cube_m - ee_m,
        "cube_blind_s": np.array([min(max(float(blind_s), 0.0), BLIND_CAP_S)]),
    }


def holding(spec: ArmSpec, commanded_rad: np.ndarray, reading_rad: np.ndarray) -> bool:
    """The gripper holds something: commanded (nearly) closed, yet it reads open by more than
    ``HOLD_MARGIN_RAD`` (an object stops the fingers). Actuator vectors: joints, then gripper.
    Servo readings only, so the env, the deploy loop and a real arm judge it alike."""
    grip, n = spec.gripper, spec.n_joints
    if grip is None or len(commanded_rad) <= n or len(reading_rad) <= n:
        return False
    span = grip.open_rad - grip.closed_rad
    commanded_closed = (float(commanded_rad[n]) - grip.closed_rad) / span < 0.25
    reading_open = (float(reading_rad[n]) - grip.closed_rad) * np.sign(span) > HOLD_MARGIN_RAD
    return bool(commanded_closed and reading_open)


def cube_estimate(
    cube_m: np.ndarray, tool_m: np.ndarray, blind_s: float, is_holding: bool
) -> np.ndarray:
    """The cube tracker's prediction with a grasp model: a cube out of sight in fingers that
    hold something moves with the tool (it is between them); otherwise it stays where it was
    last seen (a cube at rest does not move). Without the first rule a lifted cube's estimate
    stays on the table, and so does ``goal_delta``: the policy cannot see its lift."""
    if blind_s > 0.0 and is_holding:
        return np.asarray(tool_m, dtype=float)
    return cube_m


def percept_shaping(
    tool_m: np.ndarray, cube_m: np.ndarray, rest_z_m: float, is_holding: bool
) -> float:
    """``PickTask.shaping`` from what an arm without MuJoCo knows: the tool and cube estimates,
    and for "both fingers on the cube" the servo readings' ``holding`` with the tool at the cube
    (``holding`` alone is also true for the few periods a gripper closing in empty air takes to
    read closed: a learner would be paid for snapping it shut anywhere). The same terms and
    weights (``fused.grasp_shaping``), so a policy fine-tuned on the arm is paid as it was
    trained."""
    apart_m = float(np.linalg.norm(np.asarray(tool_m) - np.asarray(cube_m)))
    reach = -REACH_WEIGHT_PER_M * apart_m
    if not (is_holding and apart_m < GRASP_NEAR_M):
        return reach
    lift = min(max(float(cube_m[2]) - rest_z_m, 0.0), LIFT_M)
    return reach + GRASP_BONUS + LIFT_WEIGHT_PER_M * lift


def lift_goal(cube_rest_m: np.ndarray) -> np.ndarray:
    """The lift point above where the cube rests (success: the cube within 2 cm of it)."""
    return np.asarray(cube_rest_m, dtype=float) + (0.0, 0.0, LIFT_M)


def sample_cube_pose(rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """Where a person puts the cube down: (xy (2,) in m, yaw in rad), in front of the arm.
    The env and the mock world draw from this one distribution (in this order)."""
    radius = rng.uniform(0.12, 0.19)
    angle = rng.uniform(-0.5, 0.5)
    yaw = rng.uniform(-np.pi / 4, np.pi / 4)
    return radius * np.array([np.cos(angle), np.sin(angle)]), float(yaw)


SUCCESS_M = 0.02
BLIND_JUDGE_S = 0.5  # a real arm: a cube unseen this long is judged by the gripper, not the camera
DROPPED_FROM_M = 0.02  # a cube that was this high and is back on the table was dropped
HOLD_MARGIN_RAD = 0.1  # gripper reading this far open of "closed" while commanded closed: holding


class PickContract(DeployContract):
    """Outside the simulator: the cube is wherever the mock world (or a person) put it; the
    episode starts once it is seen and still, and latches the lift goal above that sighting.
    Success is the cube within 2 cm of the lift goal at the end: from the truth in sim and mock;
    on a real arm from the cube tracker, or, while the fingers hide it, from the tool position
    when the gripper reads blocked (holding something) while commanded closed."""

    task = "pick"
    objects = ("cube",)

    def setup(self) -> None:
        self.goal = np.zeros(3)
        self._true_goal: np.ndarray | None = None
        self._rest_z_m = 0.0
        self._distance_m = float("nan")
        self._lift_m = 0.0
        self._max_lift_m = 0.0
        self._grasped_ever = False
        self._grasped_now = False
        self._holding_now = False  # the servo readings say the fingers hold something
        self._blind_periods = 0
        self._periods = 0
        self._max_blind_s = 0.0
        # the last readings' tool, cube estimate and grasp: ``shaping``'s inputs, kept so the
        # deploy loop (which never asks) pays nothing for it
        self._last_seen: tuple[np.ndarray, np.ndarray, bool] | None = None

    def placement(self, rng: np.random.Generator) -> dict[str, np.ndarray]:
        xy, yaw = sample_cube_pose(rng)
        return {"cube": np.array([xy[0], xy[1], yaw])}

    def begin(self, percept: Percept) -> None:
        _, cube = need(percept, "cube")
        self.goal = lift_goal(cube)
        self._holding_now = False

    def observe_arm(self, reading_rad: np.ndarray, commanded_rad: np.ndarray) -> None:
        self._holding_now = holding(self.spec, commanded_rad, reading_rad)

    def readings(self, percept: Percept, step: int) -> dict[str, np.ndarray]:
        tool, cube = need(percept, "cube")
        blind = percept.blind_s("cube")
        cube = cube_estimate(cube, tool, blind, self._holding_now)
        self._periods += 1
        self._blind_periods += int(blind > 0.0)
        self._max_blind_s = max(self._max_blind_s, blind)
        self._last_seen = (tool, cube, self._holding_now)
        return {
            "ee_pos": tool,
            **cube_readings(tool, cube, blind),
            "goal_pos": self.goal,
            "goal_delta": self.goal - cube,
        }

    def goal_m(self, percept: Percept, step: int) -> np.ndarray | None:
        return self.goal

    def shaping(self) -> float | None:
        if self._last_seen is None:
            return None
        tool, cube, is_holding = self._last_seen
        return percept_shaping(tool, cube, self.goal[2] - LIFT_M, is_holding)

    def _holding(self, view: View) -> bool:
        if view.commanded_rad is None:
            return False
        return holding(self.spec, view.commanded_rad, view.actuators_rad)

    def score(self, view: View, step: int) -> str | None:
        cube = view.objects["cube"]
        blind = view.blind_s.get("cube", 0.0) > BLIND_JUDGE_S
        if not view.truth and blind and self._holding(view):
            cube = view.tool_m  # in the fingers, out of sight
        if self._true_goal is None:  # the first judged period: where the cube rests
            self._true_goal = lift_goal(cube) if view.truth else self.goal
            self._rest_z_m = float(cube[2])
        grasped = view.grasped if view.grasped is not None else self._holding(view)
        self._grasped_now = bool(grasped)
        self._grasped_ever |= self._grasped_now
        self._lift_m = float(cube[2]) - self._rest_z_m
        self._max_lift_m = max(self._max_lift_m, self._lift_m)
        self._distance_m = float(np.linalg.norm(cube - self._true_goal))
        was_up = self._max_lift_m >= DROPPED_FROM_M
        if was_up and self._lift_m < 0.5 * DROPPED_FROM_M and not self._grasped_now:
            return f"cube dropped mid-lift (it had been {self._max_lift_m * 100:.1f} cm up)"
        return None

    def outcome(self) -> Outcome:
        d = self._distance_m
        return Outcome(
            d < SUCCESS_M,
            d,
            {
                "final_distance_m": d,
                "grasped": self._grasped_now,
                "grasped_ever": self._grasped_ever,
                "lift_m": self._lift_m,
                "max_lift_m": self._max_lift_m,
                "cube_blind_max_s": self._max_blind_s,
                "cube_blind_fraction": self._blind_periods / max(self._periods, 1),
            },
        )


@register_task
class PickTask(Task):
    name = "pick"
    scene = "pick"
    uses_gripper = True
    success_threshold_m = 0.02
    start_modes = (START_DEFAULT, START_HELD)
    occludable = True  # the fingers hide the cube's markers during a grasp
    command_fields = True
    contract = PickContract
    # Observed: the cube estimate (``cube_estimate``: with the tool while the fingers hold it
    # out of sight) against the lift goal.
    goal_rule = "object_to_goal"
    hold_margin_rad = HOLD_MARGIN_RAD
    blind_cap_s = BLIND_CAP_S
    shaping_rule = "grasp_lift"  # ``shaping``, compiled into the step's observation call

    def __init__(self) -> None:
        super().__init__()
        self.goal_m = np.zeros(3)
        self.rest_z_m = 0.0  # cube centre height resting on the table
        self._cube_qadr = -1
        self._finger_geoms: frozenset[int] = frozenset()
        self._cube_xpos = np.zeros(3)  # set with the ids at the first reset
        self._cube_points = np.zeros((1, 3))
        self._placed = np.zeros(3)  # x, y (m), yaw (rad): where ``reset`` put the cube
        # ``fused.grasp_shaping``'s inputs: [cube geom, finger geoms] (at the first reset) and
        # the ``fused.G_*`` slots (the resting height at every reset)
        # (``fused.grasp_reach``: then a contact reach for the cube and each finger)
        self.shaping_prm = np.zeros(fused.N_GRASP_PRM + 1 + len(names.FINGER_GEOMS))
        self.shaping_prm[fused.G_REACH_PER_M] = REACH_WEIGHT_PER_M
        self.shaping_prm[fused.G_BONUS] = GRASP_BONUS
        self.shaping_prm[fused.G_LIFT_PER_M] = LIFT_WEIGHT_PER_M
        self.shaping_prm[fused.G_LIFT_CAP_M] = LIFT_M

    def reset(self, env: Arm3Env, rng: np.random.Generator) -> None:
        m = env.model
        if self._cube_qadr < 0:
            self._cube_qadr = int(m.joint(names.CUBE_JOINT).qposadr[0])
            self._cube_body = m.body(names.CUBE_BODY).id
            self._cube_geom = m.geom(names.CUBE_GEOM).id
            self._finger_geoms = frozenset(m.geom(g).id for g in names.FINGER_GEOMS)
            fingers = sorted(self._finger_geoms)
            self.shaping_ids = np.array([self._cube_geom, *fingers], dtype=np.int32)
            # views of MuJoCo's buffer (valid while the env's data lives): read every step
            self._cube_xpos = env.data.xpos[self._cube_body]
            self._cube_points = env.data.xpos[self._cube_body : self._cube_body + 1]
        xy, yaw = sample_cube_pose(rng)
        xy = xy + env.dr_params.get("object", {}).get("init_xy_offset_m", np.zeros(2))
        half = float(m.geom_size[env.ids.cube_geom][2])
        q = env.data.qpos
        a = self._cube_qadr
        q[a : a + 3] = (xy[0], xy[1], half)
        q[a + 3 : a + 7] = (np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2))
        self.rest_z_m = half
        self.shaping_prm[fused.G_REST_Z] = half
        # how far the cube and each finger reach for a contact, after this episode's DR; with
        # explicit contact pairs (their own margins) the contact list is always read
        ids = self.shaping_ids
        reach = m.geom_rbound[ids] + m.geom_margin[ids] if m.npair == 0 else np.inf
        self.shaping_prm[fused.N_GRASP_PRM :] = reach
        self._placed = np.array([xy[0], xy[1], yaw])
        self.goal_m = lift_goal(np.array([xy[0], xy[1], half]))
        self.obs_aux[0] = self.goal_m
        env.data.mocap_pos[0] = self.goal_m  # the env's reset runs mj_forward next

    def placement(self, env: Arm3Env) -> dict[str, np.ndarray]:
        return {"cube": self._placed.copy()}

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
        mujoco.mj_forward(m, d)  # where ``reset`` put the cube
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
        return self._cube_xpos

    def true_points(self, env: Arm3Env) -> np.ndarray:
        return self._cube_points

    def true_goals(self, env: Arm3Env) -> tuple[np.ndarray, np.ndarray]:
        return self._cube_xpos, self.goal_m

    def extra_fields(self) -> tuple[ObsField, ...]:
        return (
            ObsField("cube_pos", 3, "m", "cube position estimate, base frame"),
            ObsField("cube_delta", 3, "m", "cube minus end effector"),
            ObsField(
                "cube_blind_s", 1, "s", f"time since the cube was last seen (cap {BLIND_CAP_S})"
            ),
        )

    def is_grasped(self, env: Arm3Env) -> bool:
        """Both fingers touch the cube (from MuJoCo's contact list)."""
        d = env.data
        if d.ncon == 0:
            return False
        # the contact list's geom columns at once: one Python object per contact costs more
        # than the physics step when the fingers press the cube
        contacts = d.contact
        g1, g2 = contacts.geom1.tolist(), contacts.geom2.tolist()
        cube, fingers = self._cube_geom, self._finger_geoms
        touching = {b for a, b in zip(g1, g2, strict=True) if a == cube and b in fingers}
        touching |= {a for a, b in zip(g1, g2, strict=True) if b == cube and a in fingers}
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
        table, and a cube knocked upwards without a grasp earns nothing from it.

        Compiled (``fused.grasp_shaping``; the state env runs it inside its observation call,
        ``shaping_rule``); ``is_grasped`` and ``lift_m`` are its reference
        (``tests/sim2real/envs/test_fused.py``)."""
        return float(
            fused.grasp_shaping(
                env.ee_position(),
                self._cube_xpos,
                env.data.contact.geom,
                self.shaping_ids,
                self.shaping_prm,
            )
        )
