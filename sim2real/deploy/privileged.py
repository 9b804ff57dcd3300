"""A privileged teacher deployed where the world knows the truth (the sim and mock backends).

Training envs hand a teacher ``Arm3Env.privileged_state``; the deploy loop hands a policy only
its observation. ``TruthTeacher`` builds the same vector from what a sim or mock backend knows
(the world's true tool and objects, the arm's readings, what the loop commanded and what the
safety filter sent), so the very teacher a student imitates runs through the deploy loop, its
safety filter, its timing and, on the mock arm, the emulated servos: the ceiling of a task on
that chain. On a real arm there is no truth and it refuses in one line.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from hardware.arm import ArmBase
from sim2real.deploy.policy_io import PolicyIO
from sim2real.deploy.worlds import World
from sim2real.envs.contract import View
from sim2real.errors import ConfigError


class _EpisodeWatch:
    """The backend's world, noting when an episode's objects are placed."""

    def __init__(self, world: World, on_new: Callable[[], None]) -> None:
        self._world, self._on_new = world, on_new
        self.places_objects = world.places_objects

    def new_episode(self, placement: dict[str, np.ndarray]) -> None:
        self._world.new_episode(placement)
        self._on_new()

    def __getattr__(self, name: str) -> Any:  # view, clear, close, table_contacts...
        return getattr(self._world, name)


class TruthTeacher:
    """``act`` (a teacher of ``Arm3Env.privileged_state``) as a deploy policy. ``bind`` gives it
    the backend's arm and world (``runner.run_policy`` calls it) and returns the world the loop
    should use (the same, watched for new episodes)."""

    def __init__(
        self,
        act: Callable[[np.ndarray], np.ndarray],
        io: PolicyIO,
        extra: Callable[[View], np.ndarray] | None = None,
    ) -> None:
        self.act, self.io = act, io
        self.extra = extra  # the task's privileged extras, from the episode's first true view
        fields = {f.name: f for f in io.builder.layout()}
        self._readings = slice(fields["joint_pos"].start, fields["joint_pos"].stop)
        self._targets = slice(fields["joint_target"].start, fields["joint_target"].stop)
        self._arm: ArmBase | None = None
        self._world: World | None = None
        self._extra: np.ndarray | None = None

    def bind(self, arm: ArmBase, world: World) -> World:
        if not world.places_objects:
            raise ConfigError(
                "a privileged teacher needs the truth: deploy it on --backend sim or mock"
            )
        self._arm, self._world = arm, world

        def new_episode() -> None:
            self._extra = None

        return _EpisodeWatch(world, new_episode)

    def privileged(self, obs: np.ndarray) -> np.ndarray:
        """``Arm3Env.privileged_state``'s layout from the backend's truth and ``obs``."""
        if self._arm is None or self._world is None:
            raise ConfigError("TruthTeacher.bind(arm, world) first")
        flat = np.asarray(obs, dtype=float).reshape(-1)
        readings, targets = flat[self._readings], flat[self._targets]
        sent = self._arm.last_sent_rad
        sent = targets if sent is None else sent
        view = self._world.view(readings, sent)
        if view is None or not view.truth:
            raise ConfigError("this world tells no truth: a privileged teacher cannot run on it")
        if self._extra is None:
            self._extra = np.zeros(0) if self.extra is None else self.extra(view)
        points = [view.objects[name] for name in self.io.contract.objects]
        return np.concatenate([readings, targets, view.tool_m, *points, sent, self._extra, flat])

    def __call__(self, obs: Any) -> np.ndarray:
        return np.asarray(self.act(self.privileged(obs)), dtype=float)
