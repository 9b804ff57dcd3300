"""ArmSpec: the single source of truth for the arm.

The MJCF twin, the host safety limits, the firmware limits header and joint calibration all derive
from one YAML file, so a limit changed here changes everywhere. Angles are radians, lengths metres.

Kinematics (the topology every hobby 3-DOF arm of this class shares):
    base_yaw about ±z at the table, shoulder pitch about ±y at ``base_height_m``, elbow pitch about
    ±y at the end of the upper arm, and a parallel linkage that keeps the gripper level. At zero the
    upper arm points up and the forearm points forward (the usual "L" pose).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from hardware import yamlio
from hardware.errors import SpecError

DEFAULT_SPEC_PATH = Path(__file__).with_name("specs") / "arm3_mg996r.yaml"
# The default hobby build: bare PWM servos, whose readings are the commanded pulses.
PWM_SPEC_PATH = Path(__file__).with_name("specs") / "arm3_mg996r_pwm.yaml"

# What an actuator's position reading is. A policy trained on one kind and run on the other sees
# something else than it learned from, and the host can only judge arrival and stalls from a
# reading that can disagree with the command.
FEEDBACK_KINDS: dict[str, str] = {
    "measured": "a sensor on the horn: a bus servo's encoder, or a PWM servo's potentiometer "
    "wired to an analog input",
    "commanded": "the pulse the servo was last sent (slewed): a bare PWM servo tells nothing back",
}
DEFAULT_FEEDBACK = "measured"  # today's specs, and so their fingerprints, say nothing else

# Topology: allowed axes per joint slot (sign flips allowed, the geometry is fixed).
_TOPOLOGY_AXES: tuple[frozenset[str], ...] = (
    frozenset({"z", "-z"}),
    frozenset({"y", "-y"}),
    frozenset({"y", "-y"}),
)
_AXIS_VECTORS: dict[str, tuple[float, float, float]] = {
    "x": (1.0, 0.0, 0.0),
    "-x": (-1.0, 0.0, 0.0),
    "y": (0.0, 1.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "z": (0.0, 0.0, 1.0),
    "-z": (0.0, 0.0, -1.0),
}


def _finite(name: str, value: float) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise SpecError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(out):
        raise SpecError(f"{name} must be finite, got {value!r}")
    return out


def _positive(name: str, value: float) -> float:
    out = _finite(name, value)
    if out <= 0:
        raise SpecError(f"{name} must be > 0, got {value!r}")
    return out


def _feedback(where: str, value: Any) -> str:
    if value not in FEEDBACK_KINDS:
        raise SpecError(
            f"{where}: feedback {value!r} is not one of {', '.join(sorted(FEEDBACK_KINDS))}"
        )
    return str(value)


def _non_negative(name: str, value: float) -> float:
    out = _finite(name, value)
    if out < 0:
        raise SpecError(f"{name} must be >= 0, got {value!r}")
    return out


@dataclass(frozen=True)
class ServoModel:
    """What a hobby servo does to a command: the ranges DR samples around and sysid fits."""

    model: str = "MG996R"
    max_speed_rad_s: float = 7.5  # datasheet 0.14 s/60° at 6 V
    stall_torque_nm: float = 1.08  # datasheet 11 kg·cm at 6 V
    deadband_rad: float = 0.0079  # 5 µs dead band over 2000 µs / π rad
    resolution_rad: float = 0.0016  # 1 µs steps of Servo.writeMicroseconds
    time_constant_s: float = 0.05  # first-order lag of the internal P loop (measured class value)
    latency_s: float = 0.02  # one 50 Hz PWM frame
    pulse_min_us: float = 500.0
    pulse_max_us: float = 2500.0
    range_rad: float = math.pi  # mechanical travel between pulse_min_us and pulse_max_us

    def __post_init__(self) -> None:
        if not self.model:
            raise SpecError("servo.model must be a non-empty string")
        _positive("servo.max_speed_rad_s", self.max_speed_rad_s)
        _positive("servo.stall_torque_nm", self.stall_torque_nm)
        _non_negative("servo.deadband_rad", self.deadband_rad)
        _non_negative("servo.resolution_rad", self.resolution_rad)
        _positive("servo.time_constant_s", self.time_constant_s)
        _non_negative("servo.latency_s", self.latency_s)
        _positive("servo.range_rad", self.range_rad)
        if _finite("servo.pulse_min_us", self.pulse_min_us) >= _finite(
            "servo.pulse_max_us", self.pulse_max_us
        ):
            raise SpecError(
                f"servo.pulse_min_us ({self.pulse_min_us}) must be below "
                f"servo.pulse_max_us ({self.pulse_max_us})"
            )

    @property
    def us_per_rad(self) -> float:
        return (self.pulse_max_us - self.pulse_min_us) / self.range_rad


@dataclass(frozen=True)
class JointSpec:
    """One actuated joint. ``servo_id`` is the bus id or PWM channel."""

    name: str
    axis: str
    lower_rad: float
    upper_rad: float
    home_rad: float = 0.0
    park_rad: float = 0.0
    servo_id: int = 0
    feedback: str = DEFAULT_FEEDBACK  # what its reading is: a key of FEEDBACK_KINDS

    def __post_init__(self) -> None:
        if not self.name or not self.name.replace("_", "").isalnum():
            raise SpecError(f"joint name must be an identifier, got {self.name!r}")
        if self.axis not in _AXIS_VECTORS:
            raise SpecError(
                f"joint {self.name}: axis {self.axis!r} is not one of {sorted(_AXIS_VECTORS)}"
            )
        lo = _finite(f"joint {self.name}: lower_rad", self.lower_rad)
        hi = _finite(f"joint {self.name}: upper_rad", self.upper_rad)
        if lo >= hi:
            raise SpecError(
                f"joint {self.name}: lower_rad ({lo}) must be below upper_rad ({hi}); "
                "the limit is inverted"
            )
        for key in ("home_rad", "park_rad"):
            v = _finite(f"joint {self.name}: {key}", getattr(self, key))
            if not lo <= v <= hi:
                raise SpecError(f"joint {self.name}: {key} ({v}) is outside [{lo}, {hi}]")
        if not isinstance(self.servo_id, int) or not 0 <= self.servo_id <= 253:
            raise SpecError(f"joint {self.name}: servo_id {self.servo_id!r} is not in 0..253")
        _feedback(f"joint {self.name}", self.feedback)

    @property
    def axis_vector(self) -> tuple[float, float, float]:
        return _AXIS_VECTORS[self.axis]

    @property
    def sign(self) -> float:
        return -1.0 if self.axis.startswith("-") else 1.0


@dataclass(frozen=True)
class LinkSpec:
    """Link lengths of the kinematic chain, in metres."""

    base_height_m: float = 0.08  # table to shoulder axis
    upper_arm_m: float = 0.12  # shoulder axis to elbow axis
    forearm_m: float = 0.12  # elbow axis to wrist axis
    tool_forward_m: float = 0.045  # wrist axis to gripper centre, horizontal (level gripper)
    tool_down_m: float = 0.035  # wrist axis to gripper centre, vertical drop

    def __post_init__(self) -> None:
        for key in ("base_height_m", "upper_arm_m", "forearm_m"):
            _positive(f"links.{key}", getattr(self, key))
        _finite("links.tool_forward_m", self.tool_forward_m)
        _finite("links.tool_down_m", self.tool_down_m)


@dataclass(frozen=True)
class GripperSpec:
    """A servo-driven parallel gripper: servo angle maps linearly to finger gap."""

    name: str = "gripper"
    servo_id: int = 3
    closed_rad: float = 0.0
    open_rad: float = 1.2
    max_gap_m: float = 0.05  # finger gap at open_rad
    max_force_n: float = 12.0  # MG90S-class, 2 cm lever
    max_speed_rad_s: float = 10.0
    feedback: str = DEFAULT_FEEDBACK  # a gripper that reads its command cannot feel a cube

    def __post_init__(self) -> None:
        _feedback("gripper", self.feedback)
        lo = _finite("gripper.closed_rad", self.closed_rad)
        hi = _finite("gripper.open_rad", self.open_rad)
        if lo == hi:
            raise SpecError(f"gripper.closed_rad and open_rad are both {lo}: no travel")
        _positive("gripper.max_gap_m", self.max_gap_m)
        _positive("gripper.max_force_n", self.max_force_n)
        _positive("gripper.max_speed_rad_s", self.max_speed_rad_s)

    @property
    def lower_rad(self) -> float:
        return min(self.closed_rad, self.open_rad)

    @property
    def upper_rad(self) -> float:
        return max(self.closed_rad, self.open_rad)

    def gap_m(self, angle_rad: float) -> float:
        frac = (angle_rad - self.closed_rad) / (self.open_rad - self.closed_rad)
        return min(max(frac, 0.0), 1.0) * self.max_gap_m


@dataclass(frozen=True)
class SafetySpec:
    """Host and firmware safety settings: the per-step clamp is on by default."""

    max_step_rad: float = 0.25  # largest change of a target between two commands
    watchdog_timeout_s: float = 0.25  # firmware holds, then detaches, with no valid frame
    hold_before_disable_s: float = 0.5

    def __post_init__(self) -> None:
        _positive("safety.max_step_rad", self.max_step_rad)
        _positive("safety.watchdog_timeout_s", self.watchdog_timeout_s)
        _non_negative("safety.hold_before_disable_s", self.hold_before_disable_s)


def _point3(name: str, value: Any) -> tuple[float, float, float] | None:
    if value is None:
        return None
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise SpecError(f"{name} must be 3 numbers [x, y, z] in metres, got {value!r}")
    x, y, z = (_finite(f"{name}[{i}]", v) for i, v in enumerate(value))
    return (x, y, z)


@dataclass(frozen=True)
class WorkspaceSpec:
    """Where the tool point and the elbow may be commanded, in the base frame (metres).

    Both stay at least ``margin_m`` above the table plane and inside the box. A box left out
    (null) is the bounding box of everything the links can reach, so only the table guards.
    This is safety configuration, not something a policy learned: it is left out of
    ``ArmSpec.fingerprint()``, so tightening it never invalidates a trained policy."""

    table_z_m: float = 0.0  # the table plane; the base stands on it
    margin_m: float = 0.008  # the fingertips reach 5 mm below the tool point: 3 mm clearance
    box_min_m: tuple[float, float, float] | None = None
    box_max_m: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        _finite("workspace.table_z_m", self.table_z_m)
        _non_negative("workspace.margin_m", self.margin_m)
        lo = _point3("workspace.box_min_m", self.box_min_m)
        hi = _point3("workspace.box_max_m", self.box_max_m)
        object.__setattr__(self, "box_min_m", lo)
        object.__setattr__(self, "box_max_m", hi)
        if (lo is None) != (hi is None):
            raise SpecError("workspace.box_min_m and box_max_m must be given together (or neither)")
        if lo is not None and hi is not None:
            if any(a >= b for a, b in zip(lo, hi, strict=True)):
                raise SpecError(
                    f"workspace.box_min_m {list(lo)} must be below box_max_m {list(hi)} on every axis"
                )
            if self.table_z_m + self.margin_m >= hi[2]:
                raise SpecError(
                    f"workspace.box_max_m z ({hi[2]}) must be above table_z_m + margin_m "
                    f"({self.table_z_m + self.margin_m})"
                )


@dataclass(frozen=True)
class ArmSpec:
    """The arm: joints, geometry, servo model, gripper, safety."""

    name: str
    joints: tuple[JointSpec, ...]
    links: LinkSpec = field(default_factory=LinkSpec)
    servo: ServoModel = field(default_factory=ServoModel)
    gripper: GripperSpec | None = field(default_factory=GripperSpec)
    safety: SafetySpec = field(default_factory=SafetySpec)
    workspace: WorkspaceSpec = field(default_factory=WorkspaceSpec)

    def __post_init__(self) -> None:
        if not self.name:
            raise SpecError("spec name must be a non-empty string")
        if len(self.joints) != len(_TOPOLOGY_AXES):
            raise SpecError(
                f"expected {len(_TOPOLOGY_AXES)} joints (base yaw, shoulder, elbow), "
                f"got {len(self.joints)}"
            )
        names = [j.name for j in self.joints]
        if len(set(names)) != len(names):
            raise SpecError(f"joint names must be unique, got {names}")
        for joint, allowed in zip(self.joints, _TOPOLOGY_AXES, strict=True):
            if joint.axis not in allowed:
                raise SpecError(
                    f"joint {joint.name}: axis {joint.axis!r} does not fit the yaw-pitch-pitch "
                    f"topology; valid: {sorted(allowed)}"
                )
            span = joint.upper_rad - joint.lower_rad
            if span > self.servo.range_rad + 1e-9:
                raise SpecError(
                    f"joint {joint.name}: limits [{joint.lower_rad}, {joint.upper_rad}] span "
                    f"{span:.4f} rad, more than the servo range {self.servo.range_rad:.4f} rad"
                )
        ids = [j.servo_id for j in self.joints] + ([self.gripper.servo_id] if self.gripper else [])
        if len(set(ids)) != len(ids):
            raise SpecError(f"servo ids must be unique, got {ids}")
        if self.gripper and self.gripper.upper_rad - self.gripper.lower_rad > self.servo.range_rad:
            raise SpecError("gripper travel exceeds the servo range")
        for pose in ("home", "park"):
            q = getattr(self, f"{pose}_rad")
            where = self.workspace_violation(q)
            if where:
                raise SpecError(f"workspace: the {pose} pose {q.tolist()} rad puts {where}")

    # ---- derived values -------------------------------------------------------------------
    @property
    def n_joints(self) -> int:
        return len(self.joints)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def lower_rad(self) -> np.ndarray:  # (n_joints,)
        return np.array([j.lower_rad for j in self.joints])

    @property
    def upper_rad(self) -> np.ndarray:  # (n_joints,)
        return np.array([j.upper_rad for j in self.joints])

    @property
    def home_rad(self) -> np.ndarray:  # (n_joints,)
        return np.array([j.home_rad for j in self.joints])

    @property
    def park_rad(self) -> np.ndarray:  # (n_joints,)
        return np.array([j.park_rad for j in self.joints])

    # Actuators = joints + gripper (when present), in that order: the vector an Arm commands.
    @property
    def n_actuators(self) -> int:
        return self.n_joints + (1 if self.gripper else 0)

    @property
    def actuator_names(self) -> tuple[str, ...]:
        return self.joint_names + ((self.gripper.name,) if self.gripper else ())

    @property
    def actuator_ids(self) -> tuple[int, ...]:
        ids = tuple(j.servo_id for j in self.joints)
        return ids + ((self.gripper.servo_id,) if self.gripper else ())

    @property
    def actuator_lower_rad(self) -> np.ndarray:  # (n_actuators,)
        extra = [self.gripper.lower_rad] if self.gripper else []
        return np.array([j.lower_rad for j in self.joints] + extra)

    @property
    def actuator_upper_rad(self) -> np.ndarray:  # (n_actuators,)
        extra = [self.gripper.upper_rad] if self.gripper else []
        return np.array([j.upper_rad for j in self.joints] + extra)

    @property
    def actuator_home_rad(self) -> np.ndarray:  # (n_actuators,); gripper open at home
        extra = [self.gripper.open_rad] if self.gripper else []
        return np.array([j.home_rad for j in self.joints] + extra)

    @property
    def actuator_park_rad(self) -> np.ndarray:  # (n_actuators,); gripper closed when parked
        extra = [self.gripper.closed_rad] if self.gripper else []
        return np.array([j.park_rad for j in self.joints] + extra)

    @property
    def actuator_feedback(self) -> tuple[str, ...]:  # (n_actuators,) keys of FEEDBACK_KINDS
        extra = (self.gripper.feedback,) if self.gripper else ()
        return tuple(j.feedback for j in self.joints) + extra

    @property
    def actuator_measured(self) -> np.ndarray:  # (n_actuators,) bool: the reading is measured
        return np.array([k == "measured" for k in self.actuator_feedback], dtype=bool)

    def fingerprint(self) -> str:
        """A short hash of everything that changes behaviour: run dirs record it. The workspace
        is left out: it is safety configuration that a policy never saw in training, and run
        dirs written before it existed must keep their fingerprint. Feedback kinds count only
        where one is not the default (``to_dict`` leaves measured ones out): a policy trained
        on commanded readings must not load for an arm that measures, and vice versa."""
        import hashlib

        d = self.to_dict()
        del d["workspace"]
        return hashlib.sha256(yamlio.dumps(d).encode()).hexdigest()[:16]

    def workspace_box_m(self) -> tuple[np.ndarray, np.ndarray]:
        """(box_min (3,), box_max (3,)) in the base frame: the spec's box, or the bounding box
        of the reach when the spec gives none."""
        ws = self.workspace
        if ws.box_min_m is not None and ws.box_max_m is not None:
            return np.array(ws.box_min_m), np.array(ws.box_max_m)
        L = self.links
        reach = L.upper_arm_m + L.forearm_m + abs(L.tool_forward_m)
        top = L.base_height_m + L.upper_arm_m + L.forearm_m + abs(L.tool_down_m)
        return np.array([-reach, -reach, ws.table_z_m]), np.array([reach, reach, top])

    def workspace_violation(self, q_rad: np.ndarray) -> str:
        """Why joint angles (3,) put the tool or the elbow outside the workspace; "" if inside.
        The reference check (for validation and tests); hardware.safety has the fast one."""
        floor = self.workspace.table_z_m + self.workspace.margin_m
        lo, hi = self.workspace_box_m()
        for point, p in (
            ("tool", self.forward_kinematics(q_rad)),
            ("elbow", self.elbow_position(q_rad)),
        ):
            if p[2] < floor:
                return (
                    f"the {point} at z={p[2]:.4f} m, below the table plane + margin ({floor:.4f} m)"
                )
            if np.any(p < lo) or np.any(p > hi):
                return (
                    f"the {point} at {np.round(p, 4).tolist()} m, outside the workspace box "
                    f"{lo.tolist()}..{hi.tolist()} m"
                )
        return ""

    # ---- kinematics -----------------------------------------------------------------------
    def forward_kinematics(self, q_rad: np.ndarray) -> np.ndarray:
        """base_p_tool (3,) in metres for joint angles (3,): the analytic twin of the MJCF."""
        q = np.asarray(q_rad, dtype=float)
        yaw = self.joints[0].sign * q[0]
        a1 = self.joints[1].sign * q[1]
        a12 = a1 + self.joints[2].sign * q[2]
        L = self.links
        r = L.upper_arm_m * math.sin(a1) + L.forearm_m * math.cos(a12) + L.tool_forward_m
        z = L.base_height_m + L.upper_arm_m * math.cos(a1) - L.forearm_m * math.sin(a12)
        z -= L.tool_down_m
        return np.array([r * math.cos(yaw), r * math.sin(yaw), z])

    def elbow_position(self, q_rad: np.ndarray) -> np.ndarray:
        """base_p_elbow (3,) in metres: the elbow axis, which nears the table when the shoulder
        leans far forward (the workspace guard checks it beside the tool)."""
        q = np.asarray(q_rad, dtype=float)
        yaw = self.joints[0].sign * q[0]
        a1 = self.joints[1].sign * q[1]
        L = self.links
        r = L.upper_arm_m * math.sin(a1)
        z = L.base_height_m + L.upper_arm_m * math.cos(a1)
        return np.array([r * math.cos(yaw), r * math.sin(yaw), z])

    def inverse_kinematics(self, base_p_tool: np.ndarray) -> np.ndarray | None:
        """Elbow-down IK, or None when the point is out of reach or outside the joint limits."""
        p = np.asarray(base_p_tool, dtype=float)
        L = self.links
        r_tool = math.hypot(p[0], p[1])
        yaw = math.atan2(p[1], p[0])
        r = r_tool - L.tool_forward_m
        z = p[2] + L.tool_down_m - L.base_height_m
        # r = l1 sin a1 + l2 cos a12 ; z = l1 cos a1 - l2 sin a12
        l1, l2 = L.upper_arm_m, L.forearm_m
        d2 = r * r + z * z
        c = (l1 * l1 + l2 * l2 - d2) / (2 * l1 * l2)  # = sin(a2) where a2 = a12 - a1
        if abs(c) > 1:
            return None
        best: np.ndarray | None = None
        for a2 in (math.asin(c), math.pi - math.asin(c)):
            k1 = l1 - l2 * math.sin(a2)
            k2 = l2 * math.cos(a2)
            # r = k1 sin a1 + k2 cos a1 ; z = k1 cos a1 - k2 sin a1
            a1 = math.atan2(r, z) - math.atan2(k2, k1)
            q = np.array(
                [
                    yaw * self.joints[0].sign,
                    a1 * self.joints[1].sign,
                    a2 * self.joints[2].sign,
                ]
            )
            q = (q + math.pi) % (2 * math.pi) - math.pi
            inside = np.all(q >= self.lower_rad - 1e-9) and np.all(q <= self.upper_rad + 1e-9)
            if inside and (best is None or abs(q[2]) < abs(best[2])):
                best = q
        return best

    # ---- io -------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Every field, except a feedback kind that is the default: files and fingerprints
        written before feedback kinds existed stay as they were."""
        d = asdict(self)
        d["joints"] = [_without_default_feedback(asdict(j)) for j in self.joints]
        if d["gripper"] is not None:
            d["gripper"] = _without_default_feedback(d["gripper"])
        return d

    @classmethod
    def from_dict(cls, data: Any, source: str = "spec") -> ArmSpec:
        """Build and validate; every error names the field and the value."""
        if not isinstance(data, dict):
            raise SpecError(
                f"{source}: expected a mapping at the top level, got {type(data).__name__}"
            )
        allowed = {"name", "joints", "links", "servo", "gripper", "safety", "workspace"}
        unknown = sorted(set(data) - allowed)
        if unknown:
            raise SpecError(f"{source}: unknown key(s) {unknown}; valid: {sorted(allowed)}")
        joints_raw = data.get("joints")
        if not isinstance(joints_raw, list):
            raise SpecError(f"{source}: 'joints' must be a list, got {joints_raw!r}")
        try:
            joints = tuple(_build(JointSpec, j, f"{source}: joint") for j in joints_raw)
            gripper_raw = data.get("gripper", {})
            return cls(
                name=str(data.get("name", "")),
                joints=joints,
                links=_build(LinkSpec, data.get("links", {}), f"{source}: links"),
                servo=_build(ServoModel, data.get("servo", {}), f"{source}: servo"),
                gripper=None
                if gripper_raw is None
                else _build(GripperSpec, gripper_raw, f"{source}: gripper"),
                safety=_build(SafetySpec, data.get("safety", {}), f"{source}: safety"),
                workspace=_build(WorkspaceSpec, data.get("workspace", {}), f"{source}: workspace"),
            )
        except SpecError as exc:
            msg = str(exc)
            raise SpecError(msg if msg.startswith(source) else f"{source}: {msg}") from None

    @classmethod
    def from_yaml(cls, path: str | Path) -> ArmSpec:
        return cls.from_dict(yamlio.load(path), source=str(path))

    def to_yaml(self, path: str | Path, header: str = "") -> None:
        yamlio.dump(path, self.to_dict(), header=header or f"ArmSpec {self.name}")

    def with_feedback(self, kinds: str | dict[str, str]) -> ArmSpec:
        """A copy whose actuators read ``kinds``: one kind for all, or {actuator name: kind}."""
        given = dict.fromkeys(self.actuator_names, kinds) if isinstance(kinds, str) else dict(kinds)
        unknown = sorted(set(given) - set(self.actuator_names))
        if unknown:
            raise SpecError(
                f"feedback names actuator(s) {unknown}; valid: {list(self.actuator_names)}"
            )
        joints = tuple(replace(j, feedback=given.get(j.name, j.feedback)) for j in self.joints)
        gripper = self.gripper
        if gripper is not None:
            gripper = replace(gripper, feedback=given.get(gripper.name, gripper.feedback))
        return replace(self, joints=joints, gripper=gripper)

    def with_servo(self, **changes: float) -> ArmSpec:
        """A copy with servo-model fields replaced (sysid writes its fit this way)."""
        return replace(self, servo=replace(self.servo, **changes))  # type: ignore[arg-type]


def _without_default_feedback(d: dict[str, Any]) -> dict[str, Any]:
    if d.get("feedback") == DEFAULT_FEEDBACK:
        del d["feedback"]
    return d


def _build(cls: Any, raw: Any, where: str) -> Any:
    if not isinstance(raw, dict):
        raise SpecError(f"{where}: expected a mapping, got {raw!r}")
    fields = set(cls.__dataclass_fields__)
    unknown = sorted(set(raw) - fields)
    if unknown:
        raise SpecError(f"{where}: unknown key(s) {unknown}; valid: {sorted(fields)}")
    return cls(**raw)


def load_spec(path: str | Path | None = None) -> ArmSpec:
    """The spec at ``path``, or the shipped default."""
    return ArmSpec.from_yaml(path if path is not None else DEFAULT_SPEC_PATH)
