"""Trace: follow a straight weld seam drawn on the table at a fixed stand-off (the seed
project's next mission). This file is the whole task: sampling, reward and success."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from hardware.spec import ArmSpec
from sim2real import model as names
from sim2real.envs.base import Task, register_task
from sim2real.envs.contract import DeployContract, Outcome, Percept, View, need
from sim2real.observation import ObsField

if TYPE_CHECKING:
    from sim2real.envs.base import Arm3Env

STANDOFF_M = 0.025  # tool height above the seam (a torch's stand-off)
APPROACH_STEPS = 10  # steps to reach the seam start before the target starts moving
SUCCESS_MEAN_ERROR_M = 0.015


def sample_seam(spec: ArmSpec, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """A seam the arm can follow end to end: (start (3,) at the stand-off height, heading rad).
    The env and the deploy worlds draw from this one distribution; the deploy worlds skip the
    seams whose end plates the rig's cameras cannot find (``TraceContract.placed_in_view``)."""
    L = names.SEAM_LENGTH_M
    for _ in range(1000):
        r, a = rng.uniform(0.11, 0.2), rng.uniform(-0.6, 0.6)
        start = np.array([r * np.cos(a), r * np.sin(a), STANDOFF_M])
        heading = rng.uniform(-np.pi, np.pi)
        d = np.array([np.cos(heading), np.sin(heading), 0.0])
        if all(
            spec.inverse_kinematics(start + s * L * d) is not None for s in np.linspace(0, 1, 5)
        ):
            break
    return start, float(heading)


def seam_point(
    start_m: np.ndarray, dir_xy: np.ndarray, step: int, episode_steps: int, dt_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """The point to follow at period ``step`` and its velocity: still at the start for the
    approach, then along the seam at constant speed to its end by the episode's last step."""
    track_steps = max(1, episode_steps - APPROACH_STEPS)
    s = np.clip((step - APPROACH_STEPS) / track_steps, 0.0, 1.0)
    target = start_m + s * names.SEAM_LENGTH_M * dir_xy
    moving = APPROACH_STEPS <= step < episode_steps
    speed = names.SEAM_LENGTH_M / (track_steps * dt_s)
    return target, (dir_xy * speed if moving else np.zeros(3))


class TraceContract(DeployContract):
    """Outside the simulator: two marker plates mark the seam's ends; the point to follow moves
    along the line between them on the episode clock, as in training. Success: mean tracking
    error below 15 mm over the tracking phase, from the truth in sim and mock."""

    task = "trace"
    objects = ("seam_start", "seam_end")
    # Some of the env's seams end at the arm: the end plate lies under its base or too far and
    # flat for one camera to decode, and no park pose shows it. Sim and mock draw again then.
    placed_in_view = True

    def setup(self) -> None:
        self._start = np.zeros(3)
        self._dir = np.array([1.0, 0.0, 0.0])
        self._true: tuple[np.ndarray, np.ndarray] | None = None
        self._err_sum_m = 0.0
        self._err_n = 0
        self._last_err_m = float("nan")

    def placement(self, rng: np.random.Generator) -> dict[str, np.ndarray]:
        start, heading = sample_seam(self.spec, rng)
        return {"seam": np.array([start[0], start[1], heading])}

    @staticmethod
    def _line(start_m: np.ndarray, end_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(start at the stand-off height, unit direction in the table plane)."""
        d = np.array([end_m[0] - start_m[0], end_m[1] - start_m[1], 0.0])
        d /= max(float(np.linalg.norm(d)), 1e-9)
        return np.array([start_m[0], start_m[1], STANDOFF_M]), d

    def begin(self, percept: Percept) -> None:
        _, start, end = need(percept, "seam_start", "seam_end")
        self._start, self._dir = self._line(start, end)

    def readings(self, percept: Percept, step: int) -> dict[str, np.ndarray]:
        (tool,) = need(percept)
        target, vel = seam_point(self._start, self._dir, step, self.episode_steps, self.dt_s)
        return {
            "ee_pos": tool,
            "goal_pos": target,
            "goal_delta": target - tool,
            "goal_vel": vel,
        }

    def goal_m(self, percept: Percept, step: int) -> np.ndarray | None:
        return seam_point(self._start, self._dir, step, self.episode_steps, self.dt_s)[0]

    def score(self, view: View, step: int) -> str | None:
        if view.truth:
            if self._true is None:
                self._true = self._line(view.objects["seam_start"], view.objects["seam_end"])
            start, d = self._true
        else:
            start, d = self._start, self._dir
        target, _ = seam_point(start, d, step, self.episode_steps, self.dt_s)
        if step + 1 > APPROACH_STEPS:  # as the env's after_step: the tracking phase only
            self._last_err_m = float(np.linalg.norm(view.tool_m - target))
            self._err_sum_m += self._last_err_m
            self._err_n += 1
        return None

    def outcome(self) -> Outcome:
        mean = self._err_sum_m / self._err_n if self._err_n else float("nan")
        return Outcome(
            bool(self._err_n) and mean < SUCCESS_MEAN_ERROR_M,
            mean,
            {"mean_tracking_error_m": mean, "final_error_m": self._last_err_m},
        )


@register_task
class TraceTask(Task):
    name = "trace"
    scene = "trace"
    success_threshold_m = SUCCESS_MEAN_ERROR_M
    # Steering on the commanded pose keeps a tracker stable under camera and servo lag (reach).
    command_fields = True
    contract = TraceContract

    def __init__(self) -> None:
        super().__init__()
        self.start_m = np.zeros(3)
        self.dir = np.array([1.0, 0.0, 0.0])
        self.target_m = np.zeros(3)
        self.velocity_m_s = np.zeros(3)
        self._err_sum_m = 0.0
        self._err_n = 0
        self._heading_rad = 0.0

    def placement(self, env: Arm3Env) -> dict[str, np.ndarray]:
        return {"seam": np.array([self.start_m[0], self.start_m[1], self._heading_rad])}

    def reset(self, env: Arm3Env, rng: np.random.Generator) -> None:
        start, heading = sample_seam(env.spec_arm, rng)
        d = np.array([np.cos(heading), np.sin(heading), 0.0])
        self.start_m, self.dir = start, d
        self._heading_rad = heading
        m = env.model
        seam = m.body_mocapid[m.body(names.SEAM_BODY).id]
        env.data.mocap_pos[seam] = (start[0], start[1], 0.0003)
        env.data.mocap_quat[seam] = (np.cos(heading / 2), 0.0, 0.0, np.sin(heading / 2))
        self._err_sum_m, self._err_n = 0.0, 0
        self._move_target(env, 0)

    def _move_target(self, env: Arm3Env, step: int) -> None:
        self.target_m, self.velocity_m_s = seam_point(
            self.start_m, self.dir, step, env.max_episode_steps, env.control_dt_s
        )
        env.data.mocap_pos[0] = self.target_m
        self.obs_aux[1] = self.velocity_m_s  # the goal_vel field

    def after_step(self, env: Arm3Env) -> None:
        if env.steps + 1 > APPROACH_STEPS:  # env.steps is incremented after this hook
            self._err_sum_m += float(np.linalg.norm(env.ee_position() - self.target_m))
            self._err_n += 1
        self._move_target(env, env.steps + 1)

    def true_points(self, env: Arm3Env) -> np.ndarray:
        return self.target_m[None]

    def true_goals(self, env: Arm3Env) -> tuple[np.ndarray, np.ndarray]:
        return env.ee_position(), self.target_m

    def extra_fields(self) -> tuple[ObsField, ...]:
        return (ObsField("goal_vel", 3, "m/s", "velocity of the seam point to follow"),)

    def success_from_distance(self, env: Arm3Env, distance_m: float) -> bool:
        """Mean tracking error along the seam, not the last step's distance (against the env's
        threshold: ``SUCCESS_MEAN_ERROR_M`` unless ``success_threshold_m`` was given)."""
        if self._err_n == 0:
            return False
        return self._err_sum_m / self._err_n < env.success_threshold_m

    @property
    def mean_tracking_error_m(self) -> float:
        return self._err_sum_m / max(self._err_n, 1)
