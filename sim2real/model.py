"""ArmSpec → MJCF: the MuJoCo twin of the arm, with its scene and a stereo camera rig.

The kinematic tree mirrors ``ArmSpec.forward_kinematics`` exactly (a test holds them to 1e-6 m).
The parallel linkage that keeps the gripper level is a passive ``wrist_level`` hinge tied by a
fixed-tendon equality (shoulder + elbow + wrist = 0), which is what the linkage does mechanically.
Servos are position actuators whose force limit is the stall torque and whose damping gives the
servo's first-order time constant (kv = tau * kp).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from hardware.spec import ArmSpec
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.scene_names import (
    CUBE_BODY,
    CUBE_GEOM,
    CUBE_JOINT,
    CUBE_MARKER_GEOM_PREFIX,
    CUBE_MARKER_TEXTURE_PX,
    EE_MARKER_GEOM,
    EE_MARKER_ID,
    EE_MARKER_POS_M,
    EE_MARKER_SIZE_M,
    EE_MARKER_TILT_RAD,
    FINGER_JOINTS,
    LEVEL_TENDON,
    LINK_ROOT_BODY,
    MARKER_CUBE,
    MARKER_FILL,
    MARKER_GEOM,
    MARKER_TEXTURE_PX,
    PATH_GEOM_PREFIX,
    SCENES,
    SEAM_BODY,
    SEAM_BODY_Z_M,
    SEAM_LENGTH_M,
    SEAM_MARKER_GEOM_PREFIX,
    SEAM_MARKERS,
    TABLE_GEOM,
    TARGET_BODY,
    TARGET_MARKER_ID,
    TARGET_MARKER_SIZE_M,
    TARGET_PLATE_GEOM,
    TARGET_SITE,
    TARGET_STAND_GEOM,
    TOOL_SITE,
    WRIST_JOINT,
)

# The names live in scene_names (no MuJoCo import there); model.NAME stays valid everywhere.
from sim2real.scene_names import FINGER_GEOMS as FINGER_GEOMS
from sim2real.scene_names import MARKER_DICTIONARY as MARKER_DICTIONARY
from sim2real.scene_names import Scene as Scene

PHYSICS_TIMESTEP_S = 0.005
# Position-servo stiffness: the stall torque is reached at this tracking error.
SERVO_SATURATION_ERROR_RAD = 0.035
# The target's post (``build_mjcf(target_stand=True)``): a 10 mm dowel, longer than any target
# is high, so its lower end is always under the table top.
TARGET_STAND_RADIUS_M = 0.005
TARGET_STAND_LENGTH_M = 0.6
# Reflected rotor inertia J_rotor·N² of an MG996R-class servo: a small brushed motor (~1e-7 kg·m²)
# behind a ~1:250 gearbox, about 0.006 kg·m²; at the stall torque the joint then reaches its rated
# 7.5 rad/s in ~40 ms. The first model used 0.002: every 50 ms command step then jerked the wrist
# at ~10 g, and MuJoCo's soft friction let a grasped cube slide out of the fingers (a scripted pick
# dropped 3.8 % of its lifts; with 0.006 none in 500, BENCHMARKS "Pick that works").
ARMATURE_KG_M2 = 0.006
# The gripper finger's damping (N·s/m): as a joint damping, integrated implicitly. As the position
# actuator's kv it sat inside the 12 N force clamp, and a free finger fell into a two-step limit
# cycle (±0.86 m/s, 4 mm apart) that jammed it half open after a grasp.
FINGER_DAMPING_NS_M = 60.0


@dataclass(frozen=True)
class CameraSpec:
    """A pinhole camera of the rig: pose in the base frame and intrinsics (vertical fov)."""

    name: str
    base_p_cam_m: tuple[float, float, float]
    look_at_m: tuple[float, float, float]
    fovy_deg: float = 45.0
    width_px: int = 640
    height_px: int = 480

    def __post_init__(self) -> None:
        if not 5.0 < self.fovy_deg < 170.0:
            raise ConfigError(f"camera {self.name}: fovy_deg {self.fovy_deg} not in (5, 170)")
        if self.width_px <= 0 or self.height_px <= 0:
            raise ConfigError(
                f"camera {self.name}: image size {self.width_px}x{self.height_px} must be positive"
            )
        if np.allclose(self.base_p_cam_m, self.look_at_m):
            raise ConfigError(f"camera {self.name}: position equals look_at {self.look_at_m}")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels: MuJoCo's fovy is the vertical field of view."""
        return 0.5 * self.height_px / math.tan(math.radians(self.fovy_deg) / 2)

    def intrinsics(self) -> np.ndarray:
        """K (3, 3) of the rendered image (square pixels, principal point at the centre)."""
        f = self.focal_px
        return np.array(
            [[f, 0.0, (self.width_px - 1) / 2], [0.0, f, (self.height_px - 1) / 2], [0, 0, 1.0]]
        )

    def base_R_cam_mujoco(self) -> np.ndarray:
        """Rotation (3, 3) whose columns are the MuJoCo camera axes (x right, y up, -z forward)."""
        fwd = np.subtract(self.look_at_m, self.base_p_cam_m)
        fwd = fwd / np.linalg.norm(fwd)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        if np.linalg.norm(right) < 1e-9:
            raise ConfigError(f"camera {self.name}: looking straight up/down is not supported")
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        return np.stack([right, up, -fwd], axis=1)

    def base_T_cam(self) -> np.ndarray:
        """Pose (4, 4) of the OpenCV camera frame (x right, y down, z forward) in the base frame."""
        R_mj = self.base_R_cam_mujoco()
        T = np.eye(4)
        T[:3, :3] = R_mj @ np.diag([1.0, -1.0, -1.0])
        T[:3, 3] = self.base_p_cam_m
        return T


def _stereo_pair(
    centre_m: tuple[float, float, float],
    look_at_m: tuple[float, float, float],
    baseline_m: float,
    fovy_deg: float,
) -> tuple[CameraSpec, CameraSpec]:
    fwd = np.subtract(look_at_m, centre_m)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    offset = right * baseline_m / 2
    left_p = tuple(float(v) for v in np.subtract(centre_m, offset))
    right_p = tuple(float(v) for v in np.add(centre_m, offset))
    # Parallel optical axes: each camera looks at the look-at point shifted by its own offset.
    left_look = tuple(float(v) for v in np.subtract(look_at_m, offset))
    right_look = tuple(float(v) for v in np.add(look_at_m, offset))
    return (
        CameraSpec("cam_left", left_p, left_look, fovy_deg),  # type: ignore[arg-type]
        CameraSpec("cam_right", right_p, right_look, fovy_deg),  # type: ignore[arg-type]
    )


@dataclass(frozen=True)
class RigSpec:
    """Two cameras forming a stereo rig in front of the arm (baseline along the camera x axis)."""

    centre_m: tuple[float, float, float] = (0.6, 0.0, 0.45)
    look_at_m: tuple[float, float, float] = (0.08, 0.0, 0.06)
    baseline_m: float = 0.1
    fovy_deg: float = 55.0
    cameras: tuple[CameraSpec, ...] = field(init=False)

    def __post_init__(self) -> None:
        if not 0.005 <= self.baseline_m <= 1.0:
            raise ConfigError(f"rig baseline_m {self.baseline_m} not in [0.005, 1.0]")
        object.__setattr__(
            self,
            "cameras",
            _stereo_pair(self.centre_m, self.look_at_m, self.baseline_m, self.fovy_deg),
        )

    def camera(self, name: str) -> CameraSpec:
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise UnknownNameError("camera", name, [c.name for c in self.cameras])


def _f(*values: float) -> str:
    return " ".join(f"{v:.9g}" for v in values)


def _quat_from_R(R: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R).reshape(-1))
    return q


def marker_fill(marker_id: int) -> float:
    """The black square's share of its texture's side, for the ``aruco_<id>`` textures."""
    return MARKER_CUBE.marker_fill if marker_id in MARKER_CUBE.face_ids else MARKER_FILL


def _marker_assets(scene: str) -> str:
    """Flat white ``aruco_<id>`` textures and materials (the images are written after compiling)."""
    sides = {TARGET_MARKER_ID: MARKER_TEXTURE_PX, EE_MARKER_ID: MARKER_TEXTURE_PX}
    if scene == "pick":
        sides.update(dict.fromkeys(MARKER_CUBE.face_ids, CUBE_MARKER_TEXTURE_PX))
    if scene == "trace":
        sides.update(dict.fromkeys((SEAM_MARKERS.start_id, SEAM_MARKERS.end_id), MARKER_TEXTURE_PX))
    return "".join(
        f'<texture name="aruco_{i}" type="2d" builtin="flat" width="{px}" height="{px}" '
        f'rgb1="1 1 1"/><material name="aruco_{i}" texture="aruco_{i}" specular="0" '
        'shininess="0"/>'
        for i, px in sides.items()
    )


def _cube_marker_geoms() -> str:
    """One thin plate per visible face, its outer surface 0.1 mm outside the cube's (where the
    tracker expects the marker, within the depth buffer's resolution): massless and
    contact-free, so the cube's physics is the training scene's."""
    half_thick = 0.0001
    geoms = []
    for marker_id in MARKER_CUBE.face_ids:
        T = MARKER_CUBE.cube_T_face(marker_id)
        pos = T[:3, 3]
        h = MARKER_CUBE.half_m
        geoms.append(
            f'<geom name="{CUBE_MARKER_GEOM_PREFIX}{marker_id}" type="box" '
            f'size="{_f(h, h, half_thick)}" pos="{_f(*pos)}" quat="{_f(*_quat_from_R(T[:3, :3]))}" '
            f'material="aruco_{marker_id}" contype="0" conaffinity="0" mass="0"/>'
        )
    return "".join(geoms)


def _seam_marker_geoms() -> str:
    """The two end plates, flat on the table on the seam's line (seam body frame: +x along it)."""
    half = SEAM_MARKERS.marker_m / MARKER_FILL / 2
    half_thick = 0.0008
    ends = (
        (SEAM_MARKERS.start_id, -SEAM_MARKERS.end_offset_m),
        (SEAM_MARKERS.end_id, SEAM_LENGTH_M + SEAM_MARKERS.end_offset_m),
    )
    return "".join(
        f'<geom name="{SEAM_MARKER_GEOM_PREFIX}{marker_id}" type="box" '
        f'size="{_f(half, half, half_thick)}" pos="{_f(x, 0, half_thick - SEAM_BODY_Z_M)}" '
        f'material="aruco_{marker_id}" contype="0" conaffinity="0"/>'
        for marker_id, x in ends
    )


def _arm_xml(spec: ArmSpec, markers: bool = False) -> tuple[str, str]:
    """(worldbody XML of the arm, tendon/equality/actuator XML)."""
    L = spec.links
    j_yaw, j_sh, j_el = spec.joints
    kp = spec.servo.stall_torque_nm / SERVO_SATURATION_ERROR_RAD
    kv = spec.servo.time_constant_s * kp
    tau = spec.servo.stall_torque_nm
    grip = spec.gripper
    fingers = ""
    if grip is not None:
        half = grip.max_gap_m / 2
        fingers = f"""
            <geom name="palm" type="box" size="0.012 0.032 0.006" pos="{_f(L.tool_forward_m - 0.01, 0, -L.tool_down_m + 0.03)}" rgba="0.25 0.25 0.28 1" class="arm"/>
            <body name="finger_left" pos="{_f(L.tool_forward_m, 0, -L.tool_down_m)}">
              <joint name="finger_left" type="slide" axis="0 1 0" range="0 {_f(half)}" damping="{_f(FINGER_DAMPING_NS_M)}" armature="0.01"/>
              <geom name="finger_left" type="box" size="0.009 0.004 0.025" pos="0 0.004 0.02" class="finger"/>
            </body>
            <body name="finger_right" pos="{_f(L.tool_forward_m, 0, -L.tool_down_m)}">
              <joint name="finger_right" type="slide" axis="0 -1 0" range="0 {_f(half)}" damping="0.5" armature="0.01"/>
              <geom name="finger_right" type="box" size="0.009 0.004 0.025" pos="0 -0.004 0.02" class="finger"/>
            </body>"""
    ee_marker = ""
    if markers:
        plate = EE_MARKER_SIZE_M / MARKER_FILL / 2
        mx, my, mz = EE_MARKER_POS_M
        ee_marker = f"""
              <geom name="ee_marker_post" type="box" size="0.004 0.004 {_f((mz - 0.008) / 2)}" pos="{_f(mx - 0.014, my, 0.008 + (mz - 0.008) / 2)}" rgba="0.2 0.2 0.2 1" contype="0" conaffinity="0" mass="0.001"/>
              <geom name="{EE_MARKER_GEOM}" type="box" size="{_f(plate, plate, 0.0008)}" pos="{_f(mx, my, mz)}" euler="0 {_f(EE_MARKER_TILT_RAD)} 0" material="aruco_{EE_MARKER_ID}" contype="0" conaffinity="0" mass="0.002"/>"""
    return (
        f"""
    <body name="base" pos="0 0 0">
      <geom name="base" type="cylinder" size="0.045 0.012" pos="0 0 0.012" rgba="0.15 0.15 0.17 1" contype="0" conaffinity="0"/>
      <body name="turret" pos="0 0 0.024">
        <joint name="{j_yaw.name}" axis="{_f(*j_yaw.axis_vector)}" range="{_f(j_yaw.lower_rad, j_yaw.upper_rad)}"/>
        <geom name="turret" type="box" size="0.03 0.025 {_f((L.base_height_m - 0.024) / 2)}" pos="0 0 {_f((L.base_height_m - 0.024) / 2)}" rgba="0.2 0.2 0.22 1" contype="0" conaffinity="0" mass="0.06"/>
        <body name="{LINK_ROOT_BODY}" pos="0 0 {_f(L.base_height_m - 0.024)}">
          <joint name="{j_sh.name}" axis="{_f(*j_sh.axis_vector)}" range="{_f(j_sh.lower_rad, j_sh.upper_rad)}"/>
          <geom name="upper_arm" type="capsule" fromto="0 0 0 0 0 {_f(L.upper_arm_m)}" size="0.012" class="arm" mass="0.055"/>
          <body name="forearm" pos="0 0 {_f(L.upper_arm_m)}">
            <joint name="{j_el.name}" axis="{_f(*j_el.axis_vector)}" range="{_f(j_el.lower_rad, j_el.upper_rad)}"/>
            <geom name="forearm" type="capsule" fromto="0 0 0 {_f(L.forearm_m)} 0 0" size="0.01" class="arm" mass="0.045"/>
            <body name="wrist" pos="{_f(L.forearm_m)} 0 0">
              <joint name="{WRIST_JOINT}" axis="0 1 0" range="-3.5 3.5" damping="0.01"/>
              <geom name="wrist" type="box" size="{_f(L.tool_forward_m / 2 + 0.005)} 0.012 0.008" pos="{_f(L.tool_forward_m / 2 - 0.005, 0, 0)}" class="arm" mass="0.03"/>
              <site name="{TOOL_SITE}" pos="{_f(L.tool_forward_m, 0, -L.tool_down_m)}" size="0.006" rgba="{"0 0 0 0" if markers else "0 0.8 0.2 0.8"}"/>{fingers}{ee_marker}
            </body>
          </body>
        </body>
      </body>
    </body>""",
        f"""
  <tendon>
    <fixed name="{LEVEL_TENDON}">
      <joint joint="{j_sh.name}" coef="{_f(j_sh.sign)}"/>
      <joint joint="{j_el.name}" coef="{_f(j_el.sign)}"/>
      <joint joint="{WRIST_JOINT}" coef="1"/>
    </fixed>
  </tendon>
  <equality>
    <tendon tendon1="{LEVEL_TENDON}" solref="0.01 1" solimp="0.9 0.95 0.001"/>
    {'<joint joint1="finger_left" joint2="finger_right" solref="0.005 1"/>' if grip else ""}
  </equality>
  <actuator>
    {"".join(f'<position name="{j.name}" joint="{j.name}" kp="{_f(kp)}" kv="{_f(kv)}" forcerange="{_f(-tau, tau)}" ctrlrange="{_f(j.lower_rad, j.upper_rad)}"/>' for j in spec.joints)}
    {f'<position name="{grip.name}" joint="finger_left" kp="{_f(grip.max_force_n / 0.004)}" kv="0" forcerange="{_f(-grip.max_force_n, grip.max_force_n)}" ctrlrange="0 {_f(grip.max_gap_m / 2)}"/>' if grip else ""}
  </actuator>""",
    )


def build_mjcf(
    spec: ArmSpec,
    scene: str = "reach",
    rig: RigSpec | None = None,
    markers: bool = False,
    target_stand: bool = False,
) -> str:
    """The MJCF text of the arm in a scene with the stereo rig.

    ``markers=True`` adds ArUco plates (on the target and on the wrist; in ``pick`` on the
    cube's five visible faces, in ``trace`` at the seam's two ends) whose textures
    ``sim2real.deploy.marker_textures.install_marker_textures`` fills in after compilation.

    ``target_stand=True`` puts the target sphere on a thin dark post down to the table, as a
    physical target needs one. It is what lets one camera see the target's depth: a floating
    sphere of 16 mm projects to the same pixel from anywhere on its viewing ray (12.7 cm of the
    reachable workspace, median, in the left camera), while the post's foot on the table fixes
    (x, y) and its visible length the height. Visual only (no contacts), hidden under the table.
    """
    if scene not in SCENES:
        raise UnknownNameError("scene", scene, SCENES)
    if scene == "pick" and spec.gripper is None:
        raise ConfigError(f"scene 'pick' needs a gripper, but spec {spec.name!r} has none")
    rig = rig or RigSpec()
    arm, extras = _arm_xml(spec, markers)
    target_plate = ""
    marker_assets = ""
    if markers:
        plate = TARGET_MARKER_SIZE_M / MARKER_FILL / 2
        target_plate = (
            f'<geom name="{TARGET_PLATE_GEOM}" type="box" size="{_f(plate, plate, 0.0008)}" '
            f'material="aruco_{TARGET_MARKER_ID}" contype="0" conaffinity="0"/>'
        )
        marker_assets = _marker_assets(scene)
    cams = []
    for cam in rig.cameras:
        quat = _quat_from_R(cam.base_R_cam_mujoco())
        cams.append(
            f'<camera name="{cam.name}" pos="{_f(*cam.base_p_cam_m)}" quat="{_f(*quat)}" '
            f'fovy="{_f(cam.fovy_deg)}" resolution="{cam.width_px} {cam.height_px}"/>'
        )
    stand = ""
    if target_stand:
        stand = (
            f'\n      <geom name="{TARGET_STAND_GEOM}" type="cylinder" '
            f'fromto="0 0 -0.008 0 0 -{_f(TARGET_STAND_LENGTH_M)}" size="{_f(TARGET_STAND_RADIUS_M)}" '
            'rgba="0.15 0.15 0.17 1" contype="0" conaffinity="0" mass="0.001"/>'
        )
    cube = ""
    if scene == "pick":
        cube = f"""
    <body name="{CUBE_BODY}" pos="0.16 0 0.0125">
      <freejoint name="{CUBE_JOINT}"/>
      <geom name="{CUBE_GEOM}" type="box" size="0.0125 0.0125 0.0125" mass="0.03" rgba="0.9 0.5 0.1 1" condim="4" friction="1.2 0.01 0.001" priority="1"/>{_cube_marker_geoms() if markers else ""}
    </body>"""
    path = ""
    if scene == "trace":
        # The seam to follow: a straight 12 cm line drawn on the table, a mocap body so the
        # task moves it per episode without touching the model (DR restore stays exact).
        n_seg = 12
        seg = SEAM_LENGTH_M / n_seg
        path = (
            f'<body name="{SEAM_BODY}" mocap="true" pos="0.15 0 {_f(SEAM_BODY_Z_M)}">'
            + "".join(
                f'<geom name="{PATH_GEOM_PREFIX}{i}" type="box" size="{_f(seg / 2)} 0.0015 0.0002" '
                f'pos="{_f((i + 0.5) * seg)} 0 0" rgba="0.1 0.1 0.1 1" contype="0" conaffinity="0"/>'
                for i in range(n_seg)
            )
            + (_seam_marker_geoms() if markers else "")
            + "</body>"
        )
    return f"""<mujoco model="{spec.name}-{scene}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{PHYSICS_TIMESTEP_S}" integrator="implicitfast" impratio="5" cone="elliptic"/>
  <visual>
    <global offwidth="1280" offheight="960"/>
    <quality shadowsize="0" offsamples="0"/>
    <headlight ambient="0.35 0.35 0.35" diffuse="0.5 0.5 0.5" specular="0 0 0"/>
  </visual>
  <default>
    <joint damping="0.05" armature="{ARMATURE_KG_M2}"/>
    <geom solref="0.01 1" solimp="0.95 0.99 0.001"/>
    <default class="arm">
      <geom contype="2" conaffinity="1" rgba="0.85 0.85 0.88 1"/>
    </default>
    <default class="finger">
      <geom contype="2" conaffinity="1" condim="4" friction="1.5 0.01 0.001" rgba="0.3 0.3 0.32 1" mass="0.008" priority="1"/>
    </default>
  </default>
  <asset>
    <texture name="table" type="2d" builtin="checker" rgb1="0.72 0.66 0.58" rgb2="0.66 0.60 0.52" width="64" height="64"/>
    <material name="table" texture="table" texrepeat="8 8"/>
    <material name="marker" rgba="0.9 0.1 0.1 1"/>
    {marker_assets}
  </asset>
  <worldbody>
    <light name="key" pos="0.3 -0.4 1.2" dir="-0.2 0.3 -1" diffuse="0.7 0.7 0.7" castshadow="false"/>
    <light name="fill" pos="-0.4 0.4 1.0" dir="0.3 -0.3 -1" diffuse="0.3 0.3 0.3" castshadow="false"/>
    <geom name="{TABLE_GEOM}" type="box" size="0.6 0.6 0.02" pos="0.1 0 -0.02" material="table" contype="1" conaffinity="1" friction="0.8 0.01 0.001"/>
    {arm}
    <body name="{TARGET_BODY}" mocap="true" pos="0.16 0 0.1">
      <site name="{TARGET_SITE}" type="sphere" size="0.008" rgba="{"0 0 0 0" if markers else "0.9 0.1 0.1 0.7"}"/>
      <geom name="{MARKER_GEOM}" type="sphere" size="0.008" material="marker" rgba="{"0 0 0 0" if markers else "0.9 0.1 0.1 1"}" contype="0" conaffinity="0"/>
      {target_plate}{stand}
    </body>{cube}
    {path}
    {"".join(cams)}
  </worldbody>{extras}
</mujoco>
"""


def build_model(
    spec: ArmSpec,
    scene: str = "reach",
    rig: RigSpec | None = None,
    markers: bool = False,
    target_stand: bool = False,
) -> mujoco.MjModel:
    """Compile the MJCF; the compiled model is the nominal one that DR restores to."""
    return mujoco.MjModel.from_xml_string(build_mjcf(spec, scene, rig, markers, target_stand))


def gripper_rad_to_finger_m(spec: ArmSpec, angle_rad: float) -> float:
    """Servo angle of the gripper → slide position of each finger (half the gap)."""
    if spec.gripper is None:
        raise ConfigError(f"spec {spec.name!r} has no gripper")
    return spec.gripper.gap_m(angle_rad) / 2


def finger_m_to_gripper_rad(spec: ArmSpec, finger_m: float) -> float:
    """Inverse of ``gripper_rad_to_finger_m`` (the reading a gripper servo would report)."""
    g = spec.gripper
    if g is None:
        raise ConfigError(f"spec {spec.name!r} has no gripper")
    frac = float(min(max(2 * finger_m / g.max_gap_m, 0.0), 1.0))  # np.clip: 10x on a scalar
    return g.closed_rad + frac * (g.open_rad - g.closed_rad)


class ArmTwin:
    """Actuator vectors (rad) ↔ MuJoCo state for one compiled model, ids resolved once.

    The env, ``SimArm`` and the virtual cameras all move the arm through this, so the wrist
    coupling and the gripper angle ↔ finger mapping live in one place.
    """

    def __init__(self, model: mujoco.MjModel, spec: ArmSpec) -> None:
        self.spec = spec
        self.qadr = np.array([model.joint(n).qposadr[0] for n in spec.joint_names])
        self.dofadr = np.array([model.joint(n).dofadr[0] for n in spec.joint_names])
        self.wrist_qadr = int(model.joint(WRIST_JOINT).qposadr[0])
        self.has_gripper = spec.gripper is not None
        self.finger_qadr = (
            np.array([model.joint(n).qposadr[0] for n in FINGER_JOINTS])
            if self.has_gripper
            else np.zeros(0, dtype=int)
        )
        self.finger_dofadr = (
            np.array([model.joint(n).dofadr[0] for n in FINGER_JOINTS])
            if self.has_gripper
            else np.zeros(0, dtype=int)
        )
        self.tool_site = model.site(TOOL_SITE).id
        self.n_joints = spec.n_joints
        j = spec.joints
        self._s1, self._s2 = j[1].sign, j[2].sign

    def set_pose(self, data: mujoco.MjData, q_rad: np.ndarray, gripper_rad: float | None) -> None:
        """Place the arm kinematically (call mj_forward/mj_kinematics afterwards)."""
        data.qpos[self.qadr] = q_rad[: self.n_joints]
        data.qpos[self.wrist_qadr] = -(self._s1 * q_rad[1] + self._s2 * q_rad[2])
        if self.has_gripper and gripper_rad is not None:
            data.qpos[self.finger_qadr] = gripper_rad_to_finger_m(self.spec, gripper_rad)

    def write_ctrl(
        self, data: mujoco.MjData, joint_ctrl_rad: np.ndarray, gripper_rad: float | None
    ) -> None:
        data.ctrl[: self.n_joints] = joint_ctrl_rad
        if self.has_gripper and gripper_rad is not None:
            data.ctrl[self.n_joints] = gripper_rad_to_finger_m(self.spec, gripper_rad)

    def unjam_fingers(self, data: mujoco.MjData) -> None:
        """Fingers back at rest where their actuator drives them (a simulated cube squeezed out
        of the fingers can leave them jammed); the caller runs mj_forward."""
        if self.has_gripper:
            data.qpos[self.finger_qadr] = data.ctrl[self.n_joints]
            data.qvel[self.finger_dofadr] = 0.0

    def joint_positions(self, data: mujoco.MjData) -> np.ndarray:
        return data.qpos[self.qadr]

    def joint_velocities(self, data: mujoco.MjData) -> np.ndarray:
        return data.qvel[self.dofadr]

    def gripper_rad(self, data: mujoco.MjData) -> float:
        return finger_m_to_gripper_rad(self.spec, float(data.qpos[self.finger_qadr[0]]))

    def actuator_positions(self, data: mujoco.MjData) -> np.ndarray:
        """(n_actuators,) joints then gripper, as a servo bus would list them."""
        q = data.qpos[self.qadr]
        return np.append(q, self.gripper_rad(data)) if self.has_gripper else q.copy()

    def actuator_velocities(self, data: mujoco.MjData) -> np.ndarray:
        """(n_actuators,) rad/s, as ``actuator_positions`` lists them (the gripper's from its
        finger slide, through the linear angle ↔ gap map)."""
        qd = data.qvel[self.dofadr]
        g = self.spec.gripper
        if g is None:
            return qd.copy()
        rad_per_m = 2 * (g.open_rad - g.closed_rad) / g.max_gap_m
        return np.append(qd, rad_per_m * float(data.qvel[self.finger_dofadr[0]]))

    def tool_position(self, data: mujoco.MjData) -> np.ndarray:
        return data.site_xpos[self.tool_site]
