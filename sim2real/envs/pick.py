"""Pick: grasp a small cube from the table and lift it at least 5 cm (gripper is a 4th action).

"Holding" (the grasp-aware cube estimate, deploy's success and put-down, the shaping on the arm)
is judged from what the arm can know, which depends on its gripper's reading kind
(``hardware.spec.FEEDBACK_KINDS``, ``HOLD_RULES``): a *measured* gripper feels the cube (its
reading stops open while it is commanded closed, ``holding``); one that reads its *command* (a
bare PWM servo) reads "closed" whether it holds a cube or nothing, so the cameras judge
(``held_seen``): the gripper closed with the cube's estimate at the tool's, and, once the
fingers hide it, still held until it is seen away from the tool. What it loses: an empty close
right beside the cube counts as a grasp until the lift shows the cube left behind, and a cube
that slips out unseen is carried in the estimate until it is seen again.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from sim2real import model as names
from sim2real.envs import fused
from sim2real.envs.base import START_DEFAULT, START_HELD, Task, register_task
from sim2real.envs.contract import DeployContract, Outcome, Percept, View, need
from sim2real.errors import ConfigError
from sim2real.observation import ActionDecoder, ObsField

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


def _gripper_closed(
    spec: ArmSpec, commanded_rad: np.ndarray, reading_rad: np.ndarray
) -> tuple[bool, bool] | None:
    """(commanded (nearly) closed, reading more than ``HOLD_MARGIN_RAD`` open of closed), or
    None without a gripper in both vectors."""
    grip, n = spec.gripper, spec.n_joints
    if grip is None or len(commanded_rad) <= n or len(reading_rad) <= n:
        return None
    span = grip.open_rad - grip.closed_rad
    commanded_closed = (float(commanded_rad[n]) - grip.closed_rad) / span < 0.25
    reading_open = (float(reading_rad[n]) - grip.closed_rad) * np.sign(span) > HOLD_MARGIN_RAD
    return commanded_closed, reading_open


def holding(spec: ArmSpec, commanded_rad: np.ndarray, reading_rad: np.ndarray) -> bool:
    """A measured gripper holds something: commanded (nearly) closed, yet it reads open by more
    than ``HOLD_MARGIN_RAD`` (an object stops the fingers). Actuator vectors: joints, then
    gripper. Servo readings only, so the env, the deploy loop and a real arm judge it alike.
    False for a gripper that reads its command (``feedback: commanded``): its reading is the
    pulse it was sent, "open" only while that pulse slews shut, never because a cube stopped
    it (``held_seen`` judges it from the cameras)."""
    grip = spec.gripper
    state = _gripper_closed(spec, commanded_rad, reading_rad)
    if grip is None or state is None or grip.feedback != "measured":
        return False
    return bool(state[0] and state[1])


def held_seen(
    spec: ArmSpec,
    commanded_rad: np.ndarray,
    reading_rad: np.ndarray,
    tool_m: np.ndarray,
    cube_m: np.ndarray,
    blind_s: float,
    was_holding: bool,
) -> bool:
    """A gripper that reads its command holds the cube, judged from the cameras: it was sent
    closed and its echo reads closed (the close is done), and the cube's estimate is within
    ``GRASP_NEAR_M`` of the tool's, or the cube is out of sight and the fingers held it the
    period before (hidden in them, it moves with the tool: ``cube_estimate``). A cube seen
    away from the tool was not taken, or was dropped. ``cube_m``: the tracker's estimate (held
    at its last sighting while blind); actuator vectors: joints, then gripper."""
    state = _gripper_closed(spec, commanded_rad, reading_rad)
    if state is None or not state[0] or state[1]:
        return False
    if blind_s > 0.0 and was_holding:
        return True
    d = np.asarray(cube_m, dtype=float) - np.asarray(tool_m, dtype=float)
    return bool(math.sqrt(float(d @ d)) < GRASP_NEAR_M)


def _held_by_reading(
    spec: ArmSpec,
    commanded_rad: np.ndarray,
    reading_rad: np.ndarray,
    tool_m: np.ndarray,
    cube_m: np.ndarray,
    blind_s: float,
    was_holding: bool,
) -> bool:
    return holding(spec, commanded_rad, reading_rad)


# (spec, commanded, reading, tool, cube, blind_s, was_holding) -> holding
HoldRule = Callable[..., bool]
# How "holding" is judged, by the gripper reading's kind (``fused.HOLD_RULES`` compiles them).
HOLD_RULES: dict[str, HoldRule] = {"measured": _held_by_reading, "commanded": held_seen}


def judge_holding(
    spec: ArmSpec,
    commanded_rad: np.ndarray,
    reading_rad: np.ndarray,
    tool_m: np.ndarray,
    cube_m: np.ndarray,
    blind_s: float,
    was_holding: bool,
) -> bool:
    """Whether the fingers hold the cube, from what this arm can know (``HOLD_RULES`` by the
    gripper's reading kind): the env's grasp-aware estimate, deploy's success, put-down and
    the shaping on the arm all ask this. ``was_holding``: the last period's judgement."""
    kind = spec.gripper.feedback if spec.gripper is not None else "measured"
    return HOLD_RULES[kind](spec, commanded_rad, reading_rad, tool_m, cube_m, blind_s, was_holding)


def cube_estimate(
    cube_m: np.ndarray,
    tool_m: np.ndarray,
    blind_s: float,
    is_holding: bool,
    carried: bool = False,
) -> tuple[np.ndarray, bool]:
    """The cube tracker's prediction with a grasp model, and whether the cube is now carried
    (the next period's ``carried``): a cube in fingers that hold it moves with the tool (it is
    between them); otherwise it stays where it was last seen (a cube at rest does not move).
    Without the first rule a lifted cube's estimate stays on the table, and so does
    ``goal_delta``: the policy cannot see its lift.

    The cube is carried once the fingers hold it with its estimate within ``HELD_AWAY_M`` of
    the tool, or hidden in them; from then on, while they hold, its estimate is the tool,
    whatever the cameras say. On the mock arm the cameras said wrong things about a lifted cube:
    the still-object tracker trailed a lifted cube by 2-3 cm, and a one-camera fit of the cube
    half hidden by the fingers put it 3-9 cm below the tool in 10 of 283 sightings; the policy
    took the cube for dropped and let go of it at the goal. Before a carry (a gripper closing in
    empty air reads "open" for a few periods) the cube is where it was seen; after a drop the
    fingers read shut, nothing is held, and the cameras judge again."""
    if not is_holding:
        return cube_m, False
    tool = np.asarray(tool_m, dtype=float)
    if blind_s > 0.0 or carried:
        return tool, True
    d = np.asarray(cube_m, dtype=float) - tool
    return cube_m, math.sqrt(float(d @ d)) <= HELD_AWAY_M


def percept_shaping(
    tool_m: np.ndarray, cube_m: np.ndarray, rest_z_m: float, is_holding: bool
) -> float:
    """``PickTask.shaping`` from what an arm without MuJoCo knows: the tool and cube estimates,
    and for "both fingers on the cube" ``judge_holding`` with the tool at the cube (a measured
    gripper's ``holding`` alone is also true for the few periods a gripper closing in empty air
    takes to read closed: a learner would be paid for snapping it shut anywhere; a commanded
    gripper's ``held_seen`` is the estimates, and pays an empty close right beside the cube
    until the lift shows it). The same terms and weights (``fused.grasp_shaping``), so a policy
    fine-tuned on the arm is paid as it was trained."""
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
HELD_AWAY_M = 0.03  # a sighting this far from the tool is not the cube the fingers hold
PUT_DOWN_ABOVE_M = 0.003  # a held cube is set down with the tool this far above its grasp height


class PickContract(DeployContract):
    """Outside the simulator: the cube is wherever the mock world (or a person) put it; the
    episode starts once it is seen and still, and latches the lift goal above that sighting.
    Success is the cube within 2 cm of the lift goal at the end: from the truth in sim and mock;
    on a real arm from the cube tracker, or, while the fingers hide it, from the tool position
    while the fingers hold it (``judge_holding``: a measured gripper reads blocked while
    commanded closed; one that reads its command is judged from the estimates, ``held_seen``,
    and so cannot tell an empty close beside the cube from a grasp until the lift shows it)."""

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
        self._holding_now = False  # the fingers hold the cube (``judge_holding``), last period
        self._judged_holding = False  # the same, on ``score``'s views
        self._carried = False  # the last cube estimate was the tool (``cube_estimate``)
        # the servo readings and targets of ``observe_arm``, and the last percept's tool (at the
        # capture of the cube's frame: ``Percept.tool_then``), cube estimate (as tracked) and
        # blind time: ``judge_holding``'s inputs
        self._arm: tuple[np.ndarray, np.ndarray] | None = None
        self._percept: tuple[np.ndarray, np.ndarray, float] | None = None
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
        self._holding_now = self._carried = False

    def observe_arm(self, reading_rad: np.ndarray, commanded_rad: np.ndarray) -> None:
        self._arm = (np.array(reading_rad, dtype=float), np.array(commanded_rad, dtype=float))

    def readings(self, percept: Percept, step: int) -> dict[str, np.ndarray]:
        tool, cube = need(percept, "cube")
        blind = percept.blind_s("cube")
        # the cube is judged against the tool at the capture time of the cube's frame
        tool_then = percept.tool_then("cube")
        tool_then = tool if tool_then is None else tool_then
        self._percept = (tool_then, cube, blind)
        if self._arm is not None:
            reading, commanded = self._arm
            self._holding_now = judge_holding(
                self.spec, commanded, reading, tool_then, cube, blind, self._holding_now
            )
        cube, self._carried = cube_estimate(cube, tool, blind, self._holding_now, self._carried)
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

    def expected_hidden(self) -> frozenset[str]:
        """The cube while the fingers hold or carry it: hidden in them by design."""
        return frozenset({"cube"}) if (self._holding_now or self._carried) else frozenset()

    def put_down(self, reading_rad: np.ndarray, commanded_rad: np.ndarray) -> np.ndarray | None:
        """A held cube goes back on the table where the tool is: the tool down to the height it
        grasped at (the cube's rest, ``PUT_DOWN_ABOVE_M`` higher), the gripper still closed.
        Homing with the cube in the fingers swung it over the table, and a park with it failed
        (the fingers could not close on the rest pose's tolerance). A gripper that reads its
        command is judged on the last percept (``judge_holding``)."""
        tool_m, cube_m, blind_s = self._percept or (np.zeros(3), np.full(3, np.inf), 0.0)
        held = judge_holding(
            self.spec, commanded_rad, reading_rad, tool_m, cube_m, blind_s, self._holding_now
        )
        if not held:
            return None
        spec, n = self.spec, self.spec.n_joints
        tool = spec.forward_kinematics(np.asarray(reading_rad[:n], dtype=float))
        floor = spec.workspace.table_z_m + spec.workspace.margin_m
        rest_z = self.goal[2] - LIFT_M if self._rest_z_m == 0.0 else self._rest_z_m
        down = np.array([tool[0], tool[1], max(rest_z + PUT_DOWN_ABOVE_M, floor + 0.001)])
        q = spec.inverse_kinematics(down)
        if q is None:
            return None
        target = np.array(commanded_rad, dtype=float, copy=True)
        target[:n] = q
        return target

    def _holding(self, view: View) -> bool:
        """``judge_holding`` on ``view`` (once per period: a commanded gripper's judgement
        carries over from the last one)."""
        if view.commanded_rad is None:
            self._judged_holding = False
            return False
        self._judged_holding = judge_holding(
            self.spec, view.commanded_rad, view.actuators_rad,
            view.tool_then_m.get("cube", view.tool_m), view.objects["cube"],
            view.blind_s.get("cube", 0.0), self._judged_holding,
        )  # fmt: skip
        return self._judged_holding

    def score(self, view: View, step: int) -> str | None:
        cube = view.objects["cube"]
        held = self._holding(view)
        blind = view.blind_s.get("cube", 0.0) > BLIND_JUDGE_S
        if not view.truth and blind and held:
            cube = view.tool_m  # in the fingers, out of sight
        if self._true_goal is None:  # the first judged period: where the cube rests
            self._true_goal = lift_goal(cube) if view.truth else self.goal
            self._rest_z_m = float(cube[2])
        grasped = view.grasped if view.grasped is not None else held
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
    grasp_near_m = GRASP_NEAR_M  # a gripper that reads its command: ``held_seen``
    held_away_m = HELD_AWAY_M  # ``cube_estimate``: a sighting away from holding fingers
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

    n_privileged_extra = 3

    def privileged_extra(self, env: Arm3Env) -> np.ndarray:
        """The lift goal (3,): 7 cm above where the cube was put down (``PickServo``'s aim)."""
        return self.goal_m

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


# ---- the privileged teacher ---------------------------------------------------------------------
# Phases of ``PickServo``, in the order a pick goes through them.
PICK_PHASES: tuple[str, ...] = ("hover", "descend", "close", "lift")


@dataclass(frozen=True)
class PickServo:
    """A scripted pick on the simulator's truth (``distill``'s ``pick_servo``): over the cube,
    down, close, lift to the goal. A pure function of ``Arm3Env.privileged_state``, so it labels
    any state a student visits (DAgger) and needs no memory of its own phase.

    Each period it picks an aim for the tool from the true tool, cube, gripper reading and what
    the safety filter sent, moves the commanded tool at most ``step_m`` towards it (straight
    lines: a joint-space step near the base swings the tool sideways into the cube) and commands
    the spec's inverse kinematics of it, corrected by the offset between the true tool and the
    spec's forward kinematics of the true joints (kinematics DR moves the tool up to ~1 cm from
    the spec's; ``ReachServo`` does the same). The aim stays above the workspace guard's floor,
    which the guard would refuse anyway.

    * **hover** ``hover_m`` above the cube until the tool is within ``xy_tol_m`` of it;
    * **descend** to ``grasp_low_m`` below the cube's centre (the fingertips reach below its
      middle), keeping over it (a wider band once low, so a tool that lags a step sideways does
      not bounce back up);
    * **close** at the cube or, where the guard's floor stops the tool higher, at that floor;
      the gripper closes at the 0.25 rad per period the safety clamp allows;
    * **lift** to the goal once the gripper was sent fully closed and reads blocked by the
      cube (``holding``'s rule, on the true reading). A gripper that closed on nothing opens
      and the pick starts over.

    It reads the true gripper angle, not the policy's reading, so it teaches on a spec whose
    gripper reads its command as well (``tests/sim2real/envs/test_commanded_readings.py``).

    Measured (``bench/pick_teacher.py``): 100 % of 500 episodes under DR ``default``.
    """

    decoder: ActionDecoder
    hover_m: float = 0.04
    xy_tol_m: float = 0.006
    close_tol_m: float = 0.006
    grasp_low_m: float = 0.004
    step_m: float = 0.02
    _n: int = field(init=False, repr=False)
    _slices: dict[str, slice] = field(init=False, repr=False)
    _floor_m: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        spec = self.decoder.spec
        if spec.n_joints != 3 or spec.gripper is None or not self.decoder.use_gripper:
            raise ConfigError(
                f"pick teacher: spec {spec.name!r} needs 3 joints and a gripper in the action"
            )
        n, n_act = spec.n_joints, spec.n_actuators
        # ``Arm3Env.privileged_state`` for pick: readings (joints, gripper), targets, the tool,
        # the cube, what was sent, the lift goal
        starts = {"q": 0, "targets": n + 1, "tool": n + 1 + n_act, "cube": n + 4 + n_act}
        sizes = {"q": n + 1, "targets": n_act, "tool": 3, "cube": 3}
        slices = {k: slice(starts[k], starts[k] + sizes[k]) for k in starts}
        slices["sent"] = slice(n + 7 + n_act, n + 7 + 2 * n_act)
        slices["goal"] = slice(n + 7 + 2 * n_act, n + 10 + 2 * n_act)
        object.__setattr__(self, "_n", n)
        object.__setattr__(self, "_slices", slices)
        floor = spec.workspace.table_z_m + spec.workspace.margin_m + 0.0005
        object.__setattr__(self, "_floor_m", floor)

    @property
    def n_inputs(self) -> int:
        return 6

    def _read(self, privileged: np.ndarray) -> dict[str, np.ndarray]:
        p = np.asarray(privileged, dtype=float)
        if len(p) < self._slices["goal"].stop:
            raise ConfigError(
                f"pick teacher: a privileged state of {len(p)} values is not pick's "
                f"(at least {self._slices['goal'].stop})"
            )
        return {k: p[sl] for k, sl in self._slices.items()}

    def decide(self, privileged: np.ndarray) -> tuple[str, np.ndarray, bool]:
        """(phase, the tool's aim (3,) m, close the gripper)."""
        v = self._read(privileged)
        grip = self.decoder.spec.gripper
        assert grip is not None
        n = self._n
        tool, cube = v["tool"], v["cube"]
        span = grip.open_rad - grip.closed_rad
        sent_closed = (v["sent"][n] - grip.closed_rad) / span < 0.05
        closing = (v["targets"][n] - grip.closed_rad) / span < 0.5
        reading_open = (v["q"][n] - grip.closed_rad) / span > 0.125
        rel = cube - tool
        apart, horiz = float(np.linalg.norm(rel)), float(np.linalg.norm(rel[:2]))
        if sent_closed and reading_open and apart < GRASP_NEAR_M:
            return "lift", v["goal"], True
        low = cube - (0.0, 0.0, self.grasp_low_m)
        if closing and apart < 0.015 and not (sent_closed and not reading_open):
            return "close", low, True
        low_enough = tool[2] < cube[2] + self.hover_m + 0.005
        if horiz > self.xy_tol_m and not (horiz < 2.5 * self.xy_tol_m and low_enough):
            return "hover", cube + (0.0, 0.0, self.hover_m), False
        # the lowest the guard lets the true tool go: its floor, plus where the true tool sits
        # above the spec's forward kinematics of the true joints
        offset_z = float(tool[2] - self.decoder.spec.forward_kinematics(v["q"][:n])[2])
        at_floor = tool[2] < self._floor_m + offset_z + 0.002 and tool[2] - cube[2] < 0.012
        close = apart < self.close_tol_m or (horiz < self.xy_tol_m and at_floor)
        return "descend", low, close

    def action(self, privileged: np.ndarray) -> np.ndarray:
        """(4,) float32 in [-1, 1]: joint steps towards the aim, the gripper open or closed."""
        spec, v = self.decoder.spec, self._read(privileged)
        n = self._n
        _, aim, close = self.decide(privileged)
        offset = v["tool"] - spec.forward_kinematics(v["q"][:n])
        commanded = spec.forward_kinematics(v["targets"][:n]) + offset
        move = aim - commanded
        dist = float(np.linalg.norm(move))
        if dist > self.step_m:
            aim = commanded + move * (self.step_m / dist)
        target = aim - offset
        target[2] = max(target[2], self._floor_m)
        q_goal = spec.inverse_kinematics(target)
        if q_goal is None:  # the corrected aim out of the spec's reach: the uncorrected one
            q_goal = spec.inverse_kinematics(aim)
        out = np.zeros(self.decoder.n_actions, dtype=np.float32)
        if q_goal is not None:
            step = (q_goal - v["targets"][:n]) / self.decoder.max_delta_rad
            out[:n] = np.clip(step, -1.0, 1.0)
        out[n] = -1.0 if close else 1.0
        return out

    def inputs(self, privileged: np.ndarray) -> np.ndarray:
        """What it decides on, in 0.1 m units: the cube's and the goal's offsets from the tool."""
        v = self._read(privileged)
        return np.concatenate((v["cube"] - v["tool"], v["goal"] - v["tool"])).astype(
            np.float32
        ) * np.float32(10.0)
