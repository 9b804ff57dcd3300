"""The MJCF twin against the spec: kinematics, stability, contacts."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from hardware.spec import load_spec
from sim2real import model as names
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.model import SCENES, RigSpec, TwinScene, build_mjcf, build_model

SPEC = load_spec()


def _set_arm(model: mujoco.MjModel, data: mujoco.MjData, q: np.ndarray) -> None:
    for name, value in zip(SPEC.joint_names, q, strict=True):
        data.qpos[model.joint(name).qposadr[0]] = value
    wrist = model.joint(names.WRIST_JOINT).qposadr[0]
    data.qpos[wrist] = -(SPEC.joints[1].sign * q[1] + SPEC.joints[2].sign * q[2])


@pytest.mark.parametrize("scene", SCENES)
def test_model_fk_matches_analytic_fk(scene: str) -> None:
    model = build_model(SPEC, scene)
    data = mujoco.MjData(model)
    site = model.site(names.TOOL_SITE).id
    rng = np.random.default_rng(0)
    worst = 0.0
    for _ in range(500):
        q = rng.uniform(SPEC.lower_rad, SPEC.upper_rad)
        _set_arm(model, data, q)
        mujoco.mj_kinematics(model, data)
        worst = max(worst, float(np.abs(data.site_xpos[site] - SPEC.forward_kinematics(q)).max()))
    assert worst < 1e-6


@pytest.mark.parametrize("scene", SCENES)
def test_one_second_of_random_controls_raises_no_warning(scene: str) -> None:
    model = build_model(SPEC, scene)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(1)
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    steps = round(1.0 / model.opt.timestep)
    for i in range(steps):
        if i % 10 == 0:
            data.ctrl[:] = rng.uniform(lo, hi)
        mujoco.mj_step(model, data)
    assert data.time == pytest.approx(1.0)
    assert np.all(data.warning.number == 0), data.warning.number
    assert np.all(np.isfinite(data.qpos))


def test_level_linkage_keeps_gripper_level_under_motion() -> None:
    model = build_model(SPEC, "reach")
    data = mujoco.MjData(model)
    rng = np.random.default_rng(2)
    wrist_body = model.body("wrist").id
    worst = 0.0
    for i in range(400):
        if i % 20 == 0:
            data.ctrl[:3] = rng.uniform(SPEC.lower_rad, SPEC.upper_rad)
        mujoco.mj_step(model, data)
        R = data.xmat[wrist_body].reshape(3, 3)
        worst = max(worst, float(abs(R[2, 0])))  # the wrist x axis must stay horizontal
    # Bang-bang joint jumps tilt it transiently (a real linkage has play too); at rest it is level.
    assert worst < 0.05
    for _ in range(200):
        mujoco.mj_step(model, data)
    assert abs(data.xmat[wrist_body].reshape(3, 3)[2, 0]) < 2e-3


def test_cube_rests_on_table_without_tunnelling_or_exploding() -> None:
    model = build_model(SPEC, "pick")
    data = mujoco.MjData(model)
    cube = model.body(names.CUBE_BODY).id
    adr = model.joint(names.CUBE_JOINT).qposadr[0]
    data.qpos[adr + 2] = 0.05  # drop it from 5 cm
    for _ in range(int(2.0 / model.opt.timestep)):
        mujoco.mj_step(model, data)
    half = model.geom_size[model.geom(names.CUBE_GEOM).id][2]
    assert data.xpos[cube][2] == pytest.approx(half, abs=1e-3)
    assert np.abs(data.cvel[cube]).max() < 1e-3
    assert np.all(data.warning.number == 0)


def test_rig_cameras_are_a_parallel_stereo_pair() -> None:
    rig = RigSpec(baseline_m=0.1)
    left, right = (c.base_T_cam() for c in rig.cameras)
    assert np.linalg.norm(left[:3, 3] - right[:3, 3]) == pytest.approx(0.1)
    np.testing.assert_allclose(left[:3, :3], right[:3, :3], atol=1e-12)
    # The right camera sits along the left camera's +x axis (OpenCV convention).
    offset_in_left = left[:3, :3].T @ (right[:3, 3] - left[:3, 3])
    np.testing.assert_allclose(offset_in_left, [0.1, 0, 0], atol=1e-12)


def test_rendered_camera_matches_its_pinhole_model() -> None:
    """A known point projects where K·[R|t] says: the rig's intrinsics are the rendered ones."""
    from sim2real.rendering import FastRenderer

    rig = RigSpec()
    model = build_model(SPEC, "reach", rig)
    data = mujoco.MjData(model)
    target = np.array([0.2, 0.05, 0.1])
    data.mocap_pos[0] = target
    mujoco.mj_forward(model, data)
    cam = rig.camera("cam_left")
    with FastRenderer(model, cam.width_px, cam.height_px) as renderer:
        img = renderer.render(data, cam.name)
    red = (img[:, :, 0] > 150) & (img[:, :, 1] < 80) & (img[:, :, 2] < 80)
    assert red.sum() > 20
    ys, xs = np.nonzero(red)
    T = np.linalg.inv(cam.base_T_cam())
    p_cam = T[:3, :3] @ target + T[:3, 3]
    uv = (cam.intrinsics() @ p_cam)[:2] / p_cam[2]
    assert np.hypot(xs.mean() - uv[0], ys.mean() - uv[1]) < 1.5


def test_bad_scene_and_rig_values_are_named() -> None:
    with pytest.raises(UnknownNameError, match="scene 'kitchen'"):
        build_model(SPEC, "kitchen")
    with pytest.raises(ConfigError, match="baseline_m 0.0001"):
        RigSpec(baseline_m=0.0001)


def _model_bytes(model: mujoco.MjModel) -> bytes:
    buf = np.zeros(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buf)
    return buf.tobytes()


@pytest.mark.parametrize("scene", SCENES)
def test_a_pickled_twin_scene_compiles_to_the_same_model_bytes(scene: str) -> None:
    """What a child process is sent (the render process, the mock arm's physics) compiles to
    the parent's twin bit for bit; MuJoCo's MJCF text (6 digits) only to a near copy."""
    import pickle

    twin = TwinScene(SPEC, scene, RigSpec(baseline_m=0.07), markers=True, target_stand=True)
    model = twin.model()
    assert _model_bytes(pickle.loads(pickle.dumps(twin)).model()) == _model_bytes(model)
    text = mujoco.MjModel.from_xml_string(build_mjcf(SPEC, scene, twin.rig, True, True))
    assert (text.ngeom, text.nbody, text.njnt, text.nu) == (
        model.ngeom, model.nbody, model.njnt, model.nu
    )  # fmt: skip
    np.testing.assert_allclose(text.actuator_gainprm, model.actuator_gainprm, rtol=1e-5)


def test_the_old_module_still_offers_every_name() -> None:
    """``sim2real.model`` re-exports the twin's modules: nothing that imports it breaks."""
    from sim2real import camera_rig, scene_names, twin, twin_mjcf

    old = {"ARMATURE_KG_M2", "FINGER_DAMPING_NS_M", "PHYSICS_TIMESTEP_S", "ArmTwin",
           "SERVO_SATURATION_ERROR_RAD", "TARGET_STAND_LENGTH_M", "TARGET_STAND_RADIUS_M",
           "CameraSpec", "RigSpec", "build_mjcf", "build_model", "marker_fill",
           "finger_m_to_gripper_rad", "gripper_rad_to_finger_m"}  # fmt: skip
    shared = {n for n in vars(scene_names) if n.isupper()}  # every name, as before
    for name in old | shared:
        assert name in names.__all__, name
    for module in (camera_rig, twin, twin_mjcf):
        for name in old & set(vars(module)):
            assert getattr(names, name) is getattr(module, name)
