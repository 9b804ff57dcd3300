"""What a task needs to run outside the simulator: its deploy contract.

Training judges a task on MuJoCo's truth and feeds the policy from sensor models. Deployment has
percepts instead: a tool estimate and named object estimates (target plate, marker cube, seam
ends) from the cameras, each with how long it has been blind. A task's ``DeployContract`` says:

* which objects perception must track (``objects``);
* how an episode starts: where a world that can place things puts them (``placement``), and
  when a real arm may start (``ready``: the cube is seen and still);
* how the observation's task fields are computed from percepts (``readings``), with the same
  pure functions the env uses on its sensor models;
* how success is judged (``score`` each period, ``outcome`` at the end): from the truth where
  a world has one (sim, mock), from the camera estimates on a real arm.

The deploy loop is generic over tasks: it never asks which task it runs.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from hardware.spec import ArmSpec


@dataclass(frozen=True)
class ObjectEstimate:
    """One tracked object in the base frame; ``blind_s`` is the time since it was last measured
    (0 when measured this period: the tracker coasts on its prediction meanwhile).
    ``tool_then_m``: the tool's estimate at the capture time of the newest frame the estimate
    comes from (where the perception keeps the joint history for it): a hidden object's
    estimate is its last sighting, compared, as the env's delay line pairs them, with the tool
    of the newest frame. Cameras see the object a frame or three late while the tool comes from
    this period's readings: during a 0.15 m/s lift the two drift 2 cm apart, so whatever
    compares them (``pick.held_seen``) compares these."""

    position_m: np.ndarray  # (3,)
    blind_s: float = 0.0
    yaw_rad: float | None = None
    tool_then_m: np.ndarray | None = None  # (3,)


@dataclass(frozen=True)
class Percept:
    """One period's estimates: the tool, and the objects the task asked for (missing: never
    seen since the episode began). ``tool_blind_s``: how long the cameras have not confirmed
    the tool (the wrist plate), 0 where the tool is not camera-measured (truth, or FK only)."""

    tool_m: np.ndarray | None
    objects: Mapping[str, ObjectEstimate] = field(default_factory=dict)
    tool_blind_s: float = 0.0

    def position(self, name: str) -> np.ndarray | None:
        est = self.objects.get(name)
        return None if est is None else est.position_m

    def blind_s(self, name: str) -> float:
        est = self.objects.get(name)
        return float("inf") if est is None else est.blind_s

    def tool_then(self, name: str) -> np.ndarray | None:
        """The tool at the capture time of ``name``'s estimate (``ObjectEstimate.tool_then_m``);
        the period's tool where the perception has no history (truth, forward kinematics)."""
        est = self.objects.get(name)
        if est is not None and est.tool_then_m is not None:
            return est.tool_then_m
        return self.tool_m


@dataclass(frozen=True)
class View:
    """What success is judged on in one period: the truth (sim, mock) or the estimates (real)."""

    tool_m: np.ndarray  # (3,)
    objects: Mapping[str, np.ndarray]  # name → (3,) position
    actuators_rad: np.ndarray  # servo readings, joints then gripper
    truth: bool  # True: from a world that knows; False: camera estimates
    grasped: bool | None = None  # contact truth where the world has physics
    blind_s: Mapping[str, float] = field(default_factory=dict)
    commanded_rad: np.ndarray | None = None  # the actuator targets last sent
    tool_then_m: Mapping[str, np.ndarray] = field(default_factory=dict)  # ``Percept.tool_then``


@dataclass(frozen=True)
class Outcome:
    success: bool
    distance_m: float  # the task's own error at the end (reach: tool-target; pick: cube-goal)
    figures: dict[str, Any] = field(default_factory=dict)  # per-task figures for --json
    reason: str | None = None  # why the episode ended early, if it did


class DeployContract(ABC):
    """One episode of a task outside the simulator. A new instance per episode."""

    task: ClassVar[str]
    objects: ClassVar[tuple[str, ...]]  # tracked objects besides the tool
    # A world that places the objects (sim, mock) draws again until the rig's cameras find them
    # all from the home pose (``deploy.placement.RigSight``): for objects that no park pose
    # reveals, such as flat plates under the arm's base. The env's distribution is not changed.
    placed_in_view: ClassVar[bool] = False
    # A still object: its estimate moved less than this over ``still_window_s`` before a start.
    still_tolerance_m: ClassVar[float] = 0.003
    still_window_s: ClassVar[float] = 0.5

    def __init__(self, spec: ArmSpec, control_hz: float, episode_steps: int) -> None:
        self.spec = spec
        self.dt_s = 1.0 / control_hz
        self.episode_steps = episode_steps
        self._recent: list[tuple[float, dict[str, np.ndarray]]] = []
        self.setup()

    def setup(self) -> None:  # noqa: B027 - optional hook
        """Initialise the episode's own state."""

    # ---- how an episode starts -------------------------------------------------------------
    @abstractmethod
    def placement(self, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """Object name → pose (position, plus yaw or heading where it has one): what a world
        that can place things does at the start, with the env's own distribution."""

    def ready(self, percept: Percept, t_s: float) -> str | None:
        """None once every object has been seen and its estimate has stood still for
        ``still_window_s``; otherwise why not yet."""
        seen = {n: percept.position(n) for n in self.objects}
        missing = [n for n, p in seen.items() if p is None]
        if missing:
            self._recent.clear()
            return f"waiting to see {', '.join(missing)}"
        self._recent.append((t_s, {n: np.asarray(p, dtype=float) for n, p in seen.items()}))
        while self._recent and t_s - self._recent[0][0] > self.still_window_s:
            self._recent.pop(0)
        if t_s - self._recent[0][0] < 0.8 * self.still_window_s:
            return "waiting for the objects to stand still"
        first = self._recent[0][1]
        moved = max(
            float(np.linalg.norm(pos[n] - first[n])) for _, pos in self._recent for n in first
        )
        if moved > self.still_tolerance_m:
            return f"objects moved {moved * 1e3:.1f} mm in {self.still_window_s} s"
        return None

    def begin(self, percept: Percept) -> None:  # noqa: B027 - optional hook
        """Latch what the episode keeps from its start (pick: the lift goal above the cube)."""

    # ---- the observation -------------------------------------------------------------------
    def observe_arm(self, reading_rad: np.ndarray, commanded_rad: np.ndarray) -> None:  # noqa: B027
        """The servo readings and the targets last sent, just before ``readings`` (pick: do
        the fingers hold the cube?)."""

    @abstractmethod
    def readings(self, percept: Percept, step: int) -> dict[str, np.ndarray]:
        """The task's observation readings (``ee_pos``, goals, task extras) at period ``step``.
        Joint readings, commanded targets and the previous action are the loop's."""

    @abstractmethod
    def goal_m(self, percept: Percept, step: int) -> np.ndarray | None:
        """The desired goal the commanded-pose fields measure against (None: the layout has
        no ``target_goal_delta``)."""

    def shaping(self) -> float | None:
        """The task's dense training shaping on the last ``readings``' percepts, for learning
        on the arm (``finetune.ArmEnv``); None: the task has no shaping that percepts can give
        (its env's shaping, if any, reads MuJoCo state only)."""
        return None

    def expected_hidden(self) -> frozenset[str]:
        """Objects the task, as judged last period, expects the cameras to lose (a cube carried
        in the fingers): the session's blind limit does not count them, since the task's own
        estimate (the carry rule) stands in for the cameras while they hide."""
        return frozenset()

    def put_down(self, reading_rad: np.ndarray, commanded_rad: np.ndarray) -> np.ndarray | None:
        """Actuator targets that set down what the arm holds before it homes or parks (the
        gripper still closed; the session opens it there), or None when it holds nothing.
        Actuator vectors: joints, then gripper."""
        return None

    # ---- success ---------------------------------------------------------------------------
    @abstractmethod
    def score(self, view: View, step: int) -> str | None:
        """Account for period ``step`` on ``view``, the world one period after that period's
        command (as the env judges a step after its physics: the loop takes it at the start of
        period ``step + 1``, and once more after the last command); returns a reason to end the
        episode early (a dropped cube), or None."""

    @abstractmethod
    def outcome(self) -> Outcome:
        """Success and figures once the episode is over."""


class MissingEstimateError(LookupError):
    """A percept the observation needs is not available this period (the loop holds still)."""


def need(percept: Percept, *object_names: str) -> tuple[np.ndarray, ...]:
    """(tool, *objects) positions, or ``MissingEstimateError`` naming the first one missing."""
    if percept.tool_m is None:
        raise MissingEstimateError("tool")
    out = [percept.tool_m]
    for name in object_names:
        p = percept.position(name)
        if p is None:
            raise MissingEstimateError(name)
        out.append(p)
    return tuple(out)
