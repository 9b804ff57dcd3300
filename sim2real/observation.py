"""The observation and action contract shared by training and deployment.

``ObservationBuilder`` turns sensor readings into the flat vector a policy sees; the envs and the
deploy loop both call it, so a policy cannot tell where it runs. ``ActionDecoder`` turns the
policy's normalised action into joint targets the same way on both sides. Each field's slice,
unit and meaning are listed by ``layout()`` and printed by ``sim2real envs --layout``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from hardware.spec import ArmSpec
from sim2real.errors import ConfigError

# A pixel observation with proprioception is ``{PIXELS_KEY: frame, PROPRIO_KEY: vector}``; the
# vector holds these state-observation fields (the env's ``proprio`` kwarg picks and orders
# them): what the arm itself knows on hardware, its servo readings and what it commanded.
PIXELS_KEY = "pixels"
PROPRIO_KEY = "proprio"
PROPRIO_FIELDS: tuple[str, ...] = ("joint_pos", "joint_target", "prev_action")


@dataclass(frozen=True)
class ObsField:
    name: str
    size: int
    unit: str
    doc: str

    def __post_init__(self) -> None:
        if self.size <= 0:
            raise ConfigError(f"observation field {self.name!r}: size {self.size} must be > 0")


@dataclass(frozen=True)
class FieldSlice:
    name: str
    start: int
    stop: int
    unit: str
    doc: str


class ObservationBuilder:
    """Concatenates named readings into one float32 vector in a fixed, documented order."""

    def __init__(self, fields: tuple[ObsField, ...]) -> None:
        names = [f.name for f in fields]
        if len(set(names)) != len(names):
            raise ConfigError(f"observation fields must be unique, got {names}")
        self.fields = fields
        self._slices: list[tuple[str, slice]] = []
        start = 0
        for f in fields:
            self._slices.append((f.name, slice(start, start + f.size)))
            start += f.size
        self.size = start

    def layout(self) -> list[FieldSlice]:
        return [
            FieldSlice(f.name, s.start, s.stop, f.unit, f.doc)
            for f, (_, s) in zip(self.fields, self._slices, strict=True)
        ]

    def build(self, readings: Mapping[str, np.ndarray]) -> np.ndarray:
        """(size,) float32. Missing or mis-sized readings raise: silent zeros hide sensor faults."""
        out = np.empty(self.size, dtype=np.float32)
        try:
            for name, sl in self._slices:
                out[sl] = readings[name]
        except KeyError as exc:
            raise ConfigError(
                f"observation reading {exc.args[0]!r} missing; expected {[n for n, _ in self._slices]}"
            ) from None
        except ValueError:
            sizes = {n: np.shape(readings[n]) for n, _ in self._slices if n in readings}
            raise ConfigError(f"observation readings have wrong sizes: {sizes}") from None
        return out

    def split(self, obs: np.ndarray) -> dict[str, np.ndarray]:
        """Inverse of ``build``, for logs and debugging."""
        return {name: np.asarray(obs)[..., sl] for name, sl in self._slices}


def command_readings(
    spec: ArmSpec, joint_targets_rad: np.ndarray, goal_m: np.ndarray | None
) -> dict[str, np.ndarray]:
    """Where the last command will put the tool, by the spec's forward kinematics.

    A Smith-predictor feature: the camera's ``goal_delta`` arrives after the servo and camera
    delays, but ``goal − fk(joint_target)`` is known the moment the command is sent, so a policy
    that steers on it does not oscillate when the loop is slower than in training.
    """
    ee_m = spec.forward_kinematics(joint_targets_rad[: spec.n_joints])
    out = {"target_ee_pos": ee_m}
    if goal_m is not None:
        out["target_goal_delta"] = goal_m - ee_m
    return out


COMMAND_FIELDS = (
    ObsField("target_ee_pos", 3, "m", "forward kinematics of joint_target, base frame"),
    ObsField("target_goal_delta", 3, "m", "desired goal minus target_ee_pos"),
)


@dataclass(frozen=True)
class ActionDecoder:
    """Normalised action in [-1, 1] → actuator targets (rad).

    Joints take *deltas* (hobby servos are position-controlled: the policy nudges the target it
    sent last); the gripper, when used, takes an absolute opening in [-1 closed, 1 open].
    """

    spec: ArmSpec
    max_delta_rad: float = 0.1
    use_gripper: bool = False
    _lo: np.ndarray = field(init=False, repr=False, compare=False)
    _hi: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not 0 < self.max_delta_rad <= self.spec.safety.max_step_rad:
            raise ConfigError(
                f"max_delta_rad {self.max_delta_rad} must be in (0, safety.max_step_rad="
                f"{self.spec.safety.max_step_rad}]: the safety clamp would cut policy actions"
            )
        if self.use_gripper and self.spec.gripper is None:
            raise ConfigError(f"spec {self.spec.name!r} has no gripper to command")
        object.__setattr__(self, "_lo", self.spec.lower_rad)  # cached: decode is in the hot path
        object.__setattr__(self, "_hi", self.spec.upper_rad)

    @property
    def n_actions(self) -> int:
        return self.spec.n_joints + (1 if self.use_gripper else 0)

    def decode(self, action: np.ndarray, previous_targets_rad: np.ndarray) -> np.ndarray:
        """(n_actuators,) new targets clipped to the joint limits."""
        a = np.minimum(np.maximum(action, -1.0), 1.0)  # np.clip is 3x slower on tiny arrays
        return self.decode_clipped(a, previous_targets_rad)

    def decode_clipped(self, a: np.ndarray, previous_targets_rad: np.ndarray) -> np.ndarray:
        """``decode`` of an action already clipped to [-1, 1] (the env clips it once, for its
        ``prev_action`` too: the step path pays for one clip, not two)."""
        n = self.spec.n_joints
        out = np.array(previous_targets_rad, dtype=float)
        joints = out[:n]
        joints += a[:n] * self.max_delta_rad
        np.maximum(joints, self._lo, out=joints)
        np.minimum(joints, self._hi, out=joints)
        if self.use_gripper and self.spec.gripper is not None:
            g = self.spec.gripper
            out[n] = g.closed_rad + (a[n] + 1.0) / 2.0 * (g.open_rad - g.closed_rad)
        return out
