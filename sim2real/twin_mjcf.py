"""ArmSpec → the twin's MuJoCo model: the arm, its scene and the stereo rig, built with
``mujoco.MjSpec`` (an element per call, the XML text written by MuJoCo from the spec).

The kinematic tree mirrors ``ArmSpec.forward_kinematics`` exactly (a test holds them to 1e-6 m).
The parallel linkage that keeps the gripper level is a passive ``wrist_level`` hinge tied by a
fixed-tendon equality (shoulder + elbow + wrist = 0), which is what the linkage does mechanically.
Servos are position actuators whose force limit is the stall torque and whose damping gives the
servo's first-order time constant (kv = tau * kp).

Every value computed from the spec passes through ``_r`` (9 significant digits): the model was
first written as MJCF text with that precision, and the arm envs are pinned bit for bit to the
model it compiled to (``tests/data/step_pin``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from hardware.spec import ArmSpec
from sim2real.camera_rig import RigSpec
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

_GEOM = mujoco.mjtGeom
_DARK = (0.15, 0.15, 0.17, 1.0)
_INVISIBLE = (0.0, 0.0, 0.0, 0.0)
_VISUAL_ONLY = {"contype": 0, "conaffinity": 0}  # drawn, never in contact


def _r(*values: float) -> list[float]:
    """Values at the 9 significant digits the MJCF text carried (see the module docstring)."""
    return [float(f"{v:.9g}") for v in values]


def _quat_from_R(R: np.ndarray) -> list[float]:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R).reshape(-1))
    return _r(*q)


def _partial(default: Sequence[float], given: Sequence[float]) -> list[float]:
    """``given`` over the leading entries of ``default`` (an MJCF attribute with fewer values
    than the field keeps the default's others, e.g. a sphere's one radius of a site's three)."""
    return [*given, *default[len(given) :]]


def marker_fill(marker_id: int) -> float:
    """The black square's share of its texture's side, for the ``aruco_<id>`` textures."""
    return MARKER_CUBE.marker_fill if marker_id in MARKER_CUBE.face_ids else MARKER_FILL


# ---- the scene around the arm ---------------------------------------------------------------
def _new_spec(name: str) -> mujoco.MjSpec:
    """Compiler, physics options, rendering quality and the default classes of every scene."""
    s = mujoco.MjSpec()
    s.modelname = name
    s.compiler.degree = False
    s.compiler.autolimits = True
    s.option.timestep = PHYSICS_TIMESTEP_S
    s.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    s.option.impratio = 5.0
    s.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    s.visual.global_.offwidth, s.visual.global_.offheight = 1280, 960
    s.visual.quality.shadowsize, s.visual.quality.offsamples = 0, 0
    s.visual.headlight.ambient = [0.35, 0.35, 0.35]
    s.visual.headlight.diffuse = [0.5, 0.5, 0.5]
    s.visual.headlight.specular = [0.0, 0.0, 0.0]
    main = s.default
    main.joint.damping = _partial(main.joint.damping, [0.05])  # [linear, polynomial terms]
    main.joint.armature = ARMATURE_KG_M2
    main.geom.solref = [0.01, 1.0]
    main.geom.solimp = _partial(main.geom.solimp, [0.95, 0.99, 0.001])
    arm = s.add_default("arm", main)
    arm.geom.contype, arm.geom.conaffinity = 2, 1
    arm.geom.rgba = [0.85, 0.85, 0.88, 1.0]
    finger = s.add_default("finger", main)
    finger.geom.contype, finger.geom.conaffinity, finger.geom.condim = 2, 1, 4
    finger.geom.friction = [1.5, 0.01, 0.001]
    finger.geom.rgba = [0.3, 0.3, 0.32, 1.0]
    finger.geom.mass, finger.geom.priority = 0.008, 1
    return s


def _texture(s: mujoco.MjSpec, name: str, builtin: mujoco.mjtBuiltin, px: int, **rgb: list[float]
             ) -> None:  # fmt: skip
    s.add_texture(name=name, type=mujoco.mjtTexture.mjTEXTURE_2D, builtin=builtin,
                  width=px, height=px, **rgb)  # fmt: skip


def _material(s: mujoco.MjSpec, name: str, texture: str | None = None, **attrs: object) -> None:
    mat = s.add_material(name=name, **attrs)
    if texture is not None:
        mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = texture


def _add_assets(s: mujoco.MjSpec, scene: str, markers: bool) -> None:
    """The table's checker, the target's red, and with ``markers`` flat white ``aruco_<id>``
    textures (their images are written after compiling, ``deploy.marker_textures``)."""
    _texture(s, "table", mujoco.mjtBuiltin.mjBUILTIN_CHECKER, 64,
             rgb1=[0.72, 0.66, 0.58], rgb2=[0.66, 0.60, 0.52])  # fmt: skip
    _material(s, "table", "table", texrepeat=[8.0, 8.0])
    _material(s, "marker", rgba=[0.9, 0.1, 0.1, 1.0])
    if not markers:
        return
    sides = {TARGET_MARKER_ID: MARKER_TEXTURE_PX, EE_MARKER_ID: MARKER_TEXTURE_PX}
    if scene == "pick":
        sides.update(dict.fromkeys(MARKER_CUBE.face_ids, CUBE_MARKER_TEXTURE_PX))
    if scene == "trace":
        sides.update(dict.fromkeys((SEAM_MARKERS.start_id, SEAM_MARKERS.end_id), MARKER_TEXTURE_PX))
    for marker_id, px in sides.items():
        name = f"aruco_{marker_id}"
        _texture(s, name, mujoco.mjtBuiltin.mjBUILTIN_FLAT, px, rgb1=[1.0, 1.0, 1.0])
        _material(s, name, name, specular=0.0, shininess=0.0)


def _add_room(s: mujoco.MjSpec) -> None:
    """Two lights without shadows (rendering on CPU) and the table top at z = 0."""
    world = s.worldbody
    world.add_light(name="key", pos=[0.3, -0.4, 1.2], dir=[-0.2, 0.3, -1.0],
                    diffuse=[0.7, 0.7, 0.7], castshadow=False)  # fmt: skip
    world.add_light(name="fill", pos=[-0.4, 0.4, 1.0], dir=[0.3, -0.3, -1.0],
                    diffuse=[0.3, 0.3, 0.3], castshadow=False)  # fmt: skip
    world.add_geom(name=TABLE_GEOM, type=_GEOM.mjGEOM_BOX, size=[0.6, 0.6, 0.02],
                   pos=[0.1, 0.0, -0.02], material="table", contype=1, conaffinity=1,
                   friction=[0.8, 0.01, 0.001])  # fmt: skip


# ---- the arm --------------------------------------------------------------------------------
def _hinge(body: mujoco.MjsBody, name: str, axis: Sequence[float], lo: float, hi: float,
           **attrs: list[float]) -> None:  # fmt: skip
    body.add_joint(name=name, type=mujoco.mjtJoint.mjJNT_HINGE, axis=_r(*axis),
                   range=_r(lo, hi), **attrs)  # fmt: skip


def _add_arm(s: mujoco.MjSpec, spec: ArmSpec, markers: bool) -> None:
    """Base, turret, upper arm, forearm and the level wrist, with the tool site (and the
    gripper, and the wrist's marker plate on its post)."""
    L = spec.links
    j_yaw, j_sh, j_el = spec.joints
    arm = s.find_default("arm")
    base = s.worldbody.add_body(name="base")
    base.add_geom(name="base", type=_GEOM.mjGEOM_CYLINDER, size=[0.045, 0.012, 0.0],
                  pos=[0.0, 0.0, 0.012], rgba=list(_DARK), **_VISUAL_ONLY)  # fmt: skip
    turret = base.add_body(name="turret", pos=[0.0, 0.0, 0.024])
    _hinge(turret, j_yaw.name, j_yaw.axis_vector, j_yaw.lower_rad, j_yaw.upper_rad)
    half_h = (L.base_height_m - 0.024) / 2
    turret.add_geom(name="turret", type=_GEOM.mjGEOM_BOX, size=[0.03, 0.025, *_r(half_h)],
                    pos=[0.0, 0.0, *_r(half_h)], rgba=[0.2, 0.2, 0.22, 1.0], mass=0.06,
                    **_VISUAL_ONLY)  # fmt: skip
    upper = turret.add_body(name=LINK_ROOT_BODY, pos=[0.0, 0.0, *_r(L.base_height_m - 0.024)])
    _hinge(upper, j_sh.name, j_sh.axis_vector, j_sh.lower_rad, j_sh.upper_rad)
    upper.add_geom(arm, name="upper_arm", type=_GEOM.mjGEOM_CAPSULE, size=[0.012, 0.0, 0.0],
                   fromto=[0.0, 0.0, 0.0, 0.0, 0.0, *_r(L.upper_arm_m)], mass=0.055)  # fmt: skip
    forearm = upper.add_body(name="forearm", pos=[0.0, 0.0, *_r(L.upper_arm_m)])
    _hinge(forearm, j_el.name, j_el.axis_vector, j_el.lower_rad, j_el.upper_rad)
    forearm.add_geom(arm, name="forearm", type=_GEOM.mjGEOM_CAPSULE, size=[0.01, 0.0, 0.0],
                     fromto=[0.0, 0.0, 0.0, *_r(L.forearm_m), 0.0, 0.0], mass=0.045)  # fmt: skip
    wrist = forearm.add_body(name="wrist", pos=[*_r(L.forearm_m), 0.0, 0.0])
    _hinge(wrist, WRIST_JOINT, (0.0, 1.0, 0.0), -3.5, 3.5, damping=[0.01, 0.0, 0.0])
    wrist.add_geom(arm, name="wrist", type=_GEOM.mjGEOM_BOX,
                   size=[*_r(L.tool_forward_m / 2 + 0.005), 0.012, 0.008],
                   pos=[*_r(L.tool_forward_m / 2 - 0.005), 0.0, 0.0], mass=0.03)  # fmt: skip
    tool = s.default.site.size
    wrist.add_site(name=TOOL_SITE, pos=_r(L.tool_forward_m, 0.0, -L.tool_down_m),
                   size=_partial(tool, [0.006]),
                   rgba=list(_INVISIBLE) if markers else [0.0, 0.8, 0.2, 0.8])  # fmt: skip
    if spec.gripper is not None:
        _add_fingers(s, spec, wrist)
    if markers:
        _add_wrist_marker(wrist)


def _add_fingers(s: mujoco.MjSpec, spec: ArmSpec, wrist: mujoco.MjsBody) -> None:
    """A palm and two slide fingers, mirrored; the right one follows the left (an equality)."""
    L, grip = spec.links, spec.gripper
    assert grip is not None
    arm, finger = s.find_default("arm"), s.find_default("finger")
    wrist.add_geom(arm, name="palm", type=_GEOM.mjGEOM_BOX, size=[0.012, 0.032, 0.006],
                   pos=_r(L.tool_forward_m - 0.01, 0.0, -L.tool_down_m + 0.03),
                   rgba=[0.25, 0.25, 0.28, 1.0])  # fmt: skip
    at = _r(L.tool_forward_m, 0.0, -L.tool_down_m)
    slide = {"type": mujoco.mjtJoint.mjJNT_SLIDE, "range": [0.0, *_r(grip.max_gap_m / 2)],
             "armature": 0.01}  # fmt: skip
    for side, sign, damping in (("left", 1.0, FINGER_DAMPING_NS_M), ("right", -1.0, 0.5)):
        body = wrist.add_body(name=f"finger_{side}", pos=at)
        body.add_joint(
            name=f"finger_{side}", axis=[0.0, sign, 0.0], damping=[damping, 0.0, 0.0], **slide
        )
        body.add_geom(finger, name=f"finger_{side}", type=_GEOM.mjGEOM_BOX,
                      size=[0.009, 0.004, 0.025], pos=[0.0, sign * 0.004, 0.02])  # fmt: skip


def _add_wrist_marker(wrist: mujoco.MjsBody) -> None:
    """The wrist's ArUco plate, tilted towards the cameras, on a thin post."""
    plate = EE_MARKER_SIZE_M / MARKER_FILL / 2
    mx, my, mz = EE_MARKER_POS_M
    wrist.add_geom(name="ee_marker_post", type=_GEOM.mjGEOM_BOX,
                   size=[0.004, 0.004, *_r((mz - 0.008) / 2)],
                   pos=_r(mx - 0.014, my, 0.008 + (mz - 0.008) / 2), rgba=[0.2, 0.2, 0.2, 1.0],
                   mass=0.001, **_VISUAL_ONLY)  # fmt: skip
    geom = wrist.add_geom(name=EE_MARKER_GEOM, type=_GEOM.mjGEOM_BOX,
                          size=[*_r(plate, plate), 0.0008], pos=_r(mx, my, mz),
                          material=f"aruco_{EE_MARKER_ID}", mass=0.002,
                          **_VISUAL_ONLY)  # fmt: skip
    geom.alt.type = mujoco.mjtOrientation.mjORIENTATION_EULER
    geom.alt.euler = [0.0, *_r(EE_MARKER_TILT_RAD), 0.0]


def _add_coupling(s: mujoco.MjSpec, spec: ArmSpec) -> None:
    """The level linkage (tendon + equality), the finger mirror, and the servos."""
    j_sh, j_el = spec.joints[1], spec.joints[2]
    level = s.add_tendon(name=LEVEL_TENDON)
    level.wrap_joint(j_sh.name, *_r(j_sh.sign))
    level.wrap_joint(j_el.name, *_r(j_el.sign))
    level.wrap_joint(WRIST_JOINT, 1.0)
    eq = s.add_equality(type=mujoco.mjtEq.mjEQ_TENDON, name1=LEVEL_TENDON, solref=[0.01, 1.0])
    eq.solimp = _partial(eq.solimp, [0.9, 0.95, 0.001])
    grip = spec.gripper
    if grip is not None:
        s.add_equality(type=mujoco.mjtEq.mjEQ_JOINT, name1="finger_left", name2="finger_right",
                       solref=[0.005, 1.0])  # fmt: skip
    kp = spec.servo.stall_torque_nm / SERVO_SATURATION_ERROR_RAD
    kv = spec.servo.time_constant_s * kp
    tau = spec.servo.stall_torque_nm
    for j in spec.joints:
        _position(s, j.name, j.name, kp, kv, tau, (j.lower_rad, j.upper_rad))
    if grip is not None:
        _position(s, grip.name, "finger_left", grip.max_force_n / 0.004, 0.0, grip.max_force_n,
                  (0.0, grip.max_gap_m / 2))  # fmt: skip


def _position(s: mujoco.MjSpec, name: str, joint: str, kp: float, kv: float, force: float,
              ctrl: tuple[float, float]) -> None:  # fmt: skip
    act = s.add_actuator(name=name, target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT,
                         forcerange=_r(-force, force), ctrlrange=_r(*ctrl))  # fmt: skip
    (kp_r,), (kv_r,) = _r(kp), _r(kv)
    act.set_to_position(kp=kp_r, kv=kv_r)


# ---- the objects of each scene --------------------------------------------------------------
def _add_target(s: mujoco.MjSpec, markers: bool, stand: bool) -> None:
    """A mocap sphere (the reach target), with its marker plate and, with ``stand``, the post a
    physical target stands on (see ``build_mjcf``)."""
    body = s.worldbody.add_body(name=TARGET_BODY, mocap=True, pos=[0.16, 0.0, 0.1])
    sphere = _GEOM.mjGEOM_SPHERE
    body.add_site(name=TARGET_SITE, type=sphere, size=_partial(s.default.site.size, [0.008]),
                  rgba=list(_INVISIBLE) if markers else [0.9, 0.1, 0.1, 0.7])  # fmt: skip
    body.add_geom(name=MARKER_GEOM, type=sphere, size=[0.008, 0.0, 0.0], material="marker",
                  rgba=list(_INVISIBLE) if markers else [0.9, 0.1, 0.1, 1.0],
                  **_VISUAL_ONLY)  # fmt: skip
    if markers:
        plate = TARGET_MARKER_SIZE_M / MARKER_FILL / 2
        body.add_geom(name=TARGET_PLATE_GEOM, type=_GEOM.mjGEOM_BOX,
                      size=[*_r(plate, plate), 0.0008], material=f"aruco_{TARGET_MARKER_ID}",
                      **_VISUAL_ONLY)  # fmt: skip
    if stand:
        body.add_geom(name=TARGET_STAND_GEOM, type=_GEOM.mjGEOM_CYLINDER,
                      size=[*_r(TARGET_STAND_RADIUS_M), 0.0, 0.0],
                      fromto=[0.0, 0.0, -0.008, 0.0, 0.0, *_r(-TARGET_STAND_LENGTH_M)],
                      rgba=list(_DARK), mass=0.001, **_VISUAL_ONLY)  # fmt: skip


def _add_cube(s: mujoco.MjSpec, markers: bool) -> None:
    """The pick's 25 mm cube on a free joint, with a marker plate on each visible face: one
    thin plate per face, its outer surface 0.1 mm outside the cube's (where the tracker expects
    the marker, within the depth buffer's resolution), massless and contact-free, so the cube's
    physics is the training scene's."""
    body = s.worldbody.add_body(name=CUBE_BODY, pos=[0.16, 0.0, 0.0125])
    body.add_freejoint(name=CUBE_JOINT)
    body.add_geom(name=CUBE_GEOM, type=_GEOM.mjGEOM_BOX, size=[0.0125, 0.0125, 0.0125],
                  mass=0.03, rgba=[0.9, 0.5, 0.1, 1.0], condim=4, friction=[1.2, 0.01, 0.001],
                  priority=1)  # fmt: skip
    if not markers:
        return
    h = MARKER_CUBE.half_m
    for marker_id in MARKER_CUBE.face_ids:
        T = MARKER_CUBE.cube_T_face(marker_id)
        body.add_geom(name=f"{CUBE_MARKER_GEOM_PREFIX}{marker_id}", type=_GEOM.mjGEOM_BOX,
                      size=_r(h, h, 0.0001), pos=_r(*T[:3, 3]), quat=_quat_from_R(T[:3, :3]),
                      material=f"aruco_{marker_id}", mass=0.0, **_VISUAL_ONLY)  # fmt: skip


def _add_seam(s: mujoco.MjSpec, markers: bool) -> None:
    """The trace's seam: a straight 12 cm line drawn on the table, a mocap body so the task moves
    it per episode without touching the model (DR restore stays exact); with ``markers``, a
    plate flat on the table at each end, on the seam's line (body frame: +x along it)."""
    body = s.worldbody.add_body(name=SEAM_BODY, mocap=True, pos=[0.15, 0.0, *_r(SEAM_BODY_Z_M)])
    n_seg = 12
    seg = SEAM_LENGTH_M / n_seg
    for i in range(n_seg):
        body.add_geom(name=f"{PATH_GEOM_PREFIX}{i}", type=_GEOM.mjGEOM_BOX,
                      size=[*_r(seg / 2), 0.0015, 0.0002], pos=[*_r((i + 0.5) * seg), 0.0, 0.0],
                      rgba=[0.1, 0.1, 0.1, 1.0], **_VISUAL_ONLY)  # fmt: skip
    if not markers:
        return
    half = SEAM_MARKERS.marker_m / MARKER_FILL / 2
    half_thick = 0.0008
    ends = (
        (SEAM_MARKERS.start_id, -SEAM_MARKERS.end_offset_m),
        (SEAM_MARKERS.end_id, SEAM_LENGTH_M + SEAM_MARKERS.end_offset_m),
    )
    for marker_id, x in ends:
        body.add_geom(name=f"{SEAM_MARKER_GEOM_PREFIX}{marker_id}", type=_GEOM.mjGEOM_BOX,
                      size=_r(half, half, half_thick), pos=_r(x, 0.0, half_thick - SEAM_BODY_Z_M),
                      material=f"aruco_{marker_id}", **_VISUAL_ONLY)  # fmt: skip


def _add_cameras(s: mujoco.MjSpec, rig: RigSpec) -> None:
    for cam in rig.cameras:
        s.worldbody.add_camera(name=cam.name, pos=_r(*cam.base_p_cam_m),
                               quat=_quat_from_R(cam.base_R_cam_mujoco()), fovy=_r(cam.fovy_deg)[0],
                               resolution=[cam.width_px, cam.height_px])  # fmt: skip


# ---- the public builders --------------------------------------------------------------------
def build_spec(
    spec: ArmSpec,
    scene: str = "reach",
    rig: RigSpec | None = None,
    markers: bool = False,
    target_stand: bool = False,
) -> mujoco.MjSpec:
    """The twin as an ``MjSpec``: the arm in a scene with the stereo rig (see ``build_mjcf``)."""
    if scene not in SCENES:
        raise UnknownNameError("scene", scene, SCENES)
    if scene == "pick" and spec.gripper is None:
        raise ConfigError(f"scene 'pick' needs a gripper, but spec {spec.name!r} has none")
    s = _new_spec(f"{spec.name}-{scene}")
    _add_assets(s, scene, markers)
    _add_room(s)
    _add_arm(s, spec, markers)
    _add_target(s, markers, target_stand)
    if scene == "pick":
        _add_cube(s, markers)
    if scene == "trace":
        _add_seam(s, markers)
    _add_cameras(s, rig or RigSpec())
    _add_coupling(s, spec)
    return s


def build_mjcf(
    spec: ArmSpec,
    scene: str = "reach",
    rig: RigSpec | None = None,
    markers: bool = False,
    target_stand: bool = False,
) -> str:
    """The MJCF text MuJoCo writes for the twin: to read, diff, or open in MuJoCo's viewer.

    MuJoCo writes 6 significant digits, so the text compiles to a near copy of the twin, not
    the twin: compile with ``build_model`` (another process: from a ``TwinScene``).

    ``markers=True`` adds ArUco plates (on the target and on the wrist; in ``pick`` on the
    cube's five visible faces, in ``trace`` at the seam's two ends) whose textures
    ``sim2real.deploy.marker_textures.install_marker_textures`` fills in after compilation.

    ``target_stand=True`` puts the target sphere on a thin dark post down to the table, as a
    physical target needs one. It is what lets one camera see the target's depth: a floating
    sphere of 16 mm projects to the same pixel from anywhere on its viewing ray (12.7 cm of the
    reachable workspace, median, in the left camera), while the post's foot on the table fixes
    (x, y) and its visible length the height. Visual only (no contacts), hidden under the table.
    """
    s = build_spec(spec, scene, rig, markers, target_stand)
    s.compile()  # MuJoCo writes the XML of a compiled spec
    return str(s.to_xml())


def build_model(
    spec: ArmSpec,
    scene: str = "reach",
    rig: RigSpec | None = None,
    markers: bool = False,
    target_stand: bool = False,
) -> mujoco.MjModel:
    """Compile the twin; the compiled model is the nominal one that DR restores to."""
    return build_spec(spec, scene, rig, markers, target_stand).compile()


@dataclass(frozen=True)
class TwinScene:
    """``build_model``'s arguments as one picklable value: what a child process (the mock arm's
    physics, the renderer) is sent to compile the same twin as its parent, bit for bit."""

    spec: ArmSpec
    scene: str = "reach"
    rig: RigSpec | None = None
    markers: bool = False
    target_stand: bool = False

    def __post_init__(self) -> None:
        if self.scene not in SCENES:
            raise UnknownNameError("scene", self.scene, SCENES)

    def model(self) -> mujoco.MjModel:
        return build_model(self.spec, self.scene, self.rig, self.markers, self.target_stand)
