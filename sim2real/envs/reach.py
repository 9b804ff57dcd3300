"""Reach: bring the tool within 1 cm of a target sampled in the reachable workspace."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from hardware.spec import ArmSpec
from sim2real.envs.base import Task, register_task
from sim2real.envs.reach_contract import ReachContract
from sim2real.envs.workspace import LIMIT_MARGIN_RAD, MIN_HEIGHT_M, MIN_RADIUS_M
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.observation import ActionDecoder

if TYPE_CHECKING:
    from sim2real.envs.base import Arm3Env


class ReachableSampler:
    """``workspace.sample_reachable`` with the spec's arrays and constants taken once: the same
    draws (``uniform(lo, hi)`` is ``lo + (hi - lo) * random(3)`` in numpy), the same forward
    kinematics in the same operations, so the same targets and generator state, at a fraction of
    the per-reset cost (``tests/sim2real/envs/test_reach_sampler.py``)."""

    def __init__(self, spec: ArmSpec, min_height_m: float = MIN_HEIGHT_M) -> None:
        self.spec = spec
        self._lo = spec.lower_rad + LIMIT_MARGIN_RAD
        self._span = (spec.upper_rad - LIMIT_MARGIN_RAD) - self._lo
        self._signs = tuple(j.sign for j in spec.joints[:3])
        L = spec.links
        self._links = (L.upper_arm_m, L.forearm_m, L.tool_forward_m, L.base_height_m)
        self._tool_down_m = L.tool_down_m
        self._min_height_m = min_height_m

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        s0, s1, s2 = self._signs
        upper, fore, fwd, base = self._links
        for _ in range(1000):
            q0, q1, q2 = (self._lo + self._span * rng.random(3)).tolist()
            yaw = s0 * q0
            a1 = s1 * q1
            a12 = a1 + s2 * q2
            r = upper * math.sin(a1) + fore * math.cos(a12) + fwd
            z = base + upper * math.cos(a1) - fore * math.sin(a12)
            z -= self._tool_down_m
            x, y = r * math.cos(yaw), r * math.sin(yaw)
            if z >= self._min_height_m and np.hypot(x, y) >= MIN_RADIUS_M:
                return np.array([x, y, z])
        raise RuntimeError(
            f"spec {self.spec.name!r}: no reachable point above {self._min_height_m} m found"
        )


@register_task
class ReachTask(Task):
    name = "reach"
    scene = "reach"
    # Steering on the commanded pose survives latency unseen in training (docs/training.md).
    command_fields = True
    contract = ReachContract

    def __init__(self) -> None:
        super().__init__()
        self.target_m = np.zeros(3)
        self._sampler: ReachableSampler | None = None

    def placement(self, env: Arm3Env) -> dict[str, np.ndarray]:
        return {"target": self.target_m.copy()}

    def reset(self, env: Arm3Env, rng: np.random.Generator) -> None:
        if self._sampler is None or self._sampler.spec is not env.spec_arm:
            self._sampler = ReachableSampler(env.spec_arm)
        self.target_m = self._sampler.sample(rng)
        env.data.mocap_pos[0] = self.target_m

    def true_points(self, env: Arm3Env) -> np.ndarray:
        return self.target_m[None]

    def true_goals(self, env: Arm3Env) -> tuple[np.ndarray, np.ndarray]:
        return env.ee_position(), self.target_m


# What a reach teacher's step closes the gap to the IK solution from (``ReachServo.steer``):
# the joint command last sent, or the true joints (each a slice of the privileged state).
STEER_FROM: tuple[str, ...] = ("command", "joints")


@dataclass(frozen=True)
class ReachServo:
    """A privileged reach teacher (``distill``'s ``reach_ik`` and ``reach_servo``): a step of
    ``gain`` towards the spec's inverse kinematics of the target, in the env's normalised
    action, ``gain · (q_goal − q_from) / max_delta_rad`` clipped to [-1, 1].

    It reads ``Arm3Env.privileged_state`` (true joints, joint targets, the tool and the target,
    m, world = base frame: the arm's base sits at the world origin). The geometry is the
    *nominal* spec (what the run trains and deploys with), corrected by the measured tool: the
    IK aims at ``target − (tool − fk(q))``, the offset between where the tool is and where the
    spec puts it. Kinematics DR (links ±4 mm, joint zeros ±0.03 rad, ``default``) moves the true
    tool up to ~1 cm from the spec's; the offset is locally constant, so one correction per step
    removes it without the teacher knowing the drawn geometry (uncorrected: 93 % within 1 cm,
    median 6.1 mm; corrected: 100 %, median 1.0 mm; ``bench/reach_teacher.py``).

    ``steer`` (one of ``STEER_FROM``) picks what the step starts from:

    * ``"command"`` (``reach_ik``, gain 1): the joint targets already sent, which are set to the
      IK solution as fast as the step allows. Servo lag and latency never wind it up; the most
      exact teacher, also on ``shifted``. But its action hinges on the kinematic offset and the
      exact command, which a camera policy perceives poorly.
    * ``"joints"`` (``reach_servo``, gain 0.4): the true joints. To first order the action is
      ``gain · J(q)⁻¹ (target − tool) / max_delta_rad``, a visual servo: a function of the tool's
      offset to the target, which the frame shows, and of the joint readings. An MLP given that
      offset and the proprioception fits it to 85-87 % agreement (every joint within 0.1) where
      it fits ``reach_ik``'s to 19 % (the same 10k frames). It integrates through the servo's lag, so the gain stays low: 0.5
      already fails on ``shifted``'s two steps of latency.
    """

    decoder: ActionDecoder
    gain: float = 1.0
    steer: str = "command"
    _n_j: int = field(init=False, repr=False)
    _from: slice = field(init=False, repr=False)
    _tool: slice = field(init=False, repr=False)

    def __post_init__(self) -> None:
        spec = self.decoder.spec
        if spec.n_joints != 3:
            raise ConfigError(
                f"reach teacher: spec {spec.name!r} has {spec.n_joints} joints, not 3"
            )
        if not 0.0 < self.gain <= 1.0:
            raise ConfigError(f"reach teacher gain must be in (0, 1], got {self.gain!r}")
        # privileged_state's layout: readings (joints + gripper when the task uses it), then one
        # target per actuator, then the tool and the task's one point
        n_read, n_j = self.decoder.n_actions, spec.n_joints
        steer_from = {"command": slice(n_read, n_read + n_j), "joints": slice(0, n_j)}
        if self.steer not in steer_from:
            raise UnknownNameError("reach teacher steer", self.steer, STEER_FROM)
        tool = n_read + spec.n_actuators
        object.__setattr__(self, "_n_j", n_j)
        object.__setattr__(self, "_from", steer_from[self.steer])
        object.__setattr__(self, "_tool", slice(tool, tool + 3))

    @property
    def n_inputs(self) -> int:
        return 6

    def action(self, privileged: np.ndarray) -> np.ndarray:
        """(n_actions,) float32 in [-1, 1]; zero (hold) when neither aim is reachable."""
        spec, p = self.decoder.spec, np.asarray(privileged, dtype=float)
        q, tool = p[: self._n_j], p[self._tool]
        goal = p[self._tool.stop : self._tool.stop + 3]
        aim = goal - (tool - spec.forward_kinematics(q))
        q_goal = spec.inverse_kinematics(aim)
        if q_goal is None:
            q_goal = spec.inverse_kinematics(goal)
        out = np.zeros(self.decoder.n_actions, dtype=np.float32)
        if q_goal is not None:
            delta = self.gain * (q_goal - p[self._from]) / self.decoder.max_delta_rad
            out[: self._n_j] = np.clip(delta, -1.0, 1.0)
        return out

    def inputs(self, privileged: np.ndarray) -> np.ndarray:
        """What it decides on, in 0.1 m units: the tool's offset to the target, and the tool
        (the auxiliary target)."""
        p = np.asarray(privileged, dtype=np.float32)
        tool = p[self._tool]
        goal = p[self._tool.stop : self._tool.stop + 3]
        return np.concatenate((goal - tool, tool)) * np.float32(10.0)
