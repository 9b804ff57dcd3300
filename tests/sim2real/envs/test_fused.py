"""The compiled step kernels (``sim2real.envs.fused``) equal their numpy references, to the bit,
on random inputs: the decoder, the servo, the sensor models with the goal rules and the layout,
and pick's shaping. ``test_step_pin`` holds whole rollouts; this holds each piece, beyond the
values a seeded rollout happens to reach (limits, NaN, every DR setting). Where the reference is
numpy's BLAS (``@``, ``np.linalg.norm``), whose kernels round differently from CPU to CPU (FMA),
the check is to one rounding (relative 1e-14) instead of the bit."""

from __future__ import annotations

import copy
import pickle
from typing import Any

import numpy as np
import pytest

import sim2real.envs as envs
from hardware.spec import load_spec
from sim2real.actuation import ServoActuation
from sim2real.envs import fused
from sim2real.envs.pick import (
    BLIND_CAP_S,
    GRASP_NEAR_M,
    HOLD_MARGIN_RAD,
    PickTask,
    cube_estimate,
    cube_readings,
    judge_holding,
    percept_shaping,
)
from sim2real.envs.reach import ReachTask
from sim2real.envs.trace import TraceTask
from sim2real.model import RigSpec, finger_m_to_gripper_rad, gripper_rad_to_finger_m
from sim2real.observation import ActionDecoder, ObservationBuilder, command_readings
from sim2real.randomization.sensing import SensorModel

SPEC = load_spec()
# Reading kinds the sensing is checked under: every reading measured (the pinned rollouts'), a
# bare PWM build (every reading the echo of its command) and a mix of both.
FEEDBACK = {
    "measured": SPEC,
    "commanded": load_spec("hardware/specs/arm3_mg996r_pwm.yaml"),
    "mixed": SPEC.with_feedback({"shoulder": "commanded", "gripper": "commanded"}),
}


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("use_gripper", [False, True])
def test_decode_is_the_action_decoder(dtype: type, use_gripper: bool) -> None:
    dec = ActionDecoder(SPEC, 0.1, use_gripper=use_gripper)
    rng = np.random.default_rng(0)
    md = dtype(dec.max_delta_rad) if dtype is np.float32 else dec.max_delta_rad
    g = SPEC.gripper
    assert g is not None
    grip = np.array([float(use_gripper), g.closed_rad, g.open_rad])
    for _ in range(2000):
        action = rng.uniform(-1.5, 1.5, dec.n_actions).astype(dtype)
        action[rng.random(dec.n_actions) < 0.05] = np.nan
        prev = rng.uniform(-3.0, 3.0, SPEC.n_actuators)
        a = np.empty_like(action)
        out = np.empty_like(prev)
        fused.decode(action, a, prev, out, SPEC.lower_rad, SPEC.upper_rad, md, grip)
        ref_a = np.minimum(np.maximum(action, -1.0), 1.0)
        np.testing.assert_array_equal(a, ref_a)
        assert a.dtype == ref_a.dtype
        np.testing.assert_array_equal(out, dec.decode(action, prev))


def test_actuate_is_the_servo_model() -> None:
    """Latency 0-2, noise, dead band, quantisation: the kernel on one ``ServoActuation``'s state
    writes what the numpy model returns on a twin, the gripper's finger command included."""
    rng = np.random.default_rng(1)
    g = SPEC.gripper
    assert g is not None
    grip = np.array([1.0, g.closed_rad, g.open_rad, g.max_gap_m])
    for case in range(24):
        params = {
            "latency_steps": case % 3,
            "action_noise_rad": 0.0 if case % 4 == 0 else rng.uniform(0, 0.01),
            "max_speed_scale": rng.uniform(0.4, 1.0),
            "deadband_rad": 0.0 if case % 5 == 0 else rng.uniform(0, 0.02),
            "quantisation_rad": 0.0 if case % 6 == 0 else rng.choice([0.0016, 0.0032]),
        }
        ref, fast = (ServoActuation(SPEC, 0.05, 3) for _ in range(2))
        for s in (ref, fast):
            s.configure(params)
            s.reset(np.array([0.1, -0.2, 0.3]))
        r_ref, r_fast = np.random.default_rng(case), np.random.default_rng(case)
        servo = fast.servo
        prm = np.array(
            [servo.max_step_rad, servo.deadband_rad, servo.quantum_rad, servo.per_quantum]
        )
        ctrl = np.zeros(4)
        for _ in range(150):
            sent = rng.uniform(-1.0, 1.0, 4) * rng.choice([0.001, 0.05, 1.0])
            want = ref(sent[:3], r_ref).copy()
            noise = fast.noise.take(r_fast) if fast.noise_rad > 0 else np.zeros(3)
            fused.actuate(
                sent, noise, fast.noise_rad, prm, servo.applied_rad, servo.queue_rad,
                servo.head, ctrl, grip,
            )  # fmt: skip
            np.testing.assert_array_equal(ctrl[:3], want, err_msg=str(params))
            assert ctrl[3] == gripper_rad_to_finger_m(SPEC, float(sent[3]))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_command_is_decode_then_actuate(dtype: type) -> None:
    """The env's one-call action side (no safety filter) writes what ``decode`` and then
    ``actuate`` on the decoded targets write, state and all, across servo settings."""
    rng = np.random.default_rng(2)
    g = SPEC.gripper
    assert g is not None
    n = SPEC.n_joints
    lo, hi = SPEC.lower_rad, SPEC.upper_rad
    decode_grip = np.array([1.0, g.closed_rad, g.open_rad])
    ctrl_grip = np.array([1.0, g.closed_rad, g.open_rad, g.max_gap_m])
    md = dtype(0.1) if dtype is np.float32 else 0.1
    for case in range(12):
        servo_prm = np.array([rng.uniform(0.01, 0.2), rng.uniform(0, 0.02), 0.0016, 625.0])
        servo_prm[2:] = (0.0, 0.0) if case % 3 == 0 else servo_prm[2:]
        cmd = np.concatenate([lo, hi, decode_grip, servo_prm, ctrl_grip])
        assert len(cmd) == 2 * n + fused.N_CMD
        latency, noise_rad = case % 3, 0.0 if case % 2 else 0.005
        start = rng.uniform(-0.5, 0.5, n)
        states = [
            (start.copy(), np.tile(start, (latency, 1)), np.zeros(1, dtype=np.int64))
            for _ in range(2)
        ]
        prev = np.append(start, g.open_rad)
        for _ in range(60):
            action = rng.uniform(-1.5, 1.5, 4).astype(dtype)
            noise = rng.standard_normal(n)
            outs = []
            for k, (applied, queue, head) in enumerate(states):
                a, targets, ctrl = np.empty_like(action), np.empty(n + 1), np.zeros(n + 1)
                if k == 0:
                    fused.decode(action, a, prev, targets, lo, hi, md, decode_grip)
                    fused.actuate(
                        targets, noise, noise_rad, servo_prm, applied, queue, head, ctrl,
                        ctrl_grip,
                    )  # fmt: skip
                else:
                    fused.command(
                        action, a, prev, targets, md, cmd, noise, noise_rad, applied, queue,
                        head, ctrl,
                    )  # fmt: skip
                outs.append((a, targets, ctrl))
            for want, got in zip(outs[0], outs[1], strict=True):
                np.testing.assert_array_equal(got, want)
            for want, got in zip(states[0], states[1], strict=True):
                np.testing.assert_array_equal(got, want)
            prev = outs[0][1]


def _sensor_pair(
    rng: np.random.Generator, n_r: int, spec: Any = SPEC, dt: float = 0.05
) -> tuple[SensorModel, SensorModel]:
    cam = RigSpec().cameras[0]
    T = cam.base_T_cam()
    params: dict[str, Any] = {
        "joint_noise_rad": rng.choice([0.0, rng.uniform(0, 0.004)]),
        "joint_bias_rad": rng.uniform(-0.01, 0.01, 3),
        "stereo_pixel_noise_px": rng.choice([0.0, rng.uniform(0.1, 0.6)]),
        "position_bias_m": rng.uniform(-0.003, 0.003, 3),
        "obs_delay_steps": int(rng.integers(0, 3)),
        "point_dropout_prob": rng.uniform(0.0, 0.3),
        "occlusion_radius_m": rng.uniform(0.03, 0.1),
        "occlusion_prob": rng.uniform(0.3, 1.0),
    }
    res = SPEC.servo.resolution_rad if rng.random() < 0.8 else 0.0
    speeds = [spec.servo.max_speed_rad_s] * spec.n_joints + [spec.gripper.max_speed_rad_s]
    echo = {
        "commanded": ~spec.actuator_measured[:n_r],
        "slew_rad_per_step": np.array(speeds[:n_r]) * dt,
    }
    pair = tuple(
        SensorModel(n_r, res, T[:3, :3], T[:3, 3], cam.focal_px, 0.1, **echo) for _ in range(2)
    )
    for s in pair:
        s.configure(params)
        s.reset()
    return pair[0], pair[1]


CASES = [  # task, obs mode "goal"?, reading kinds (``FEEDBACK``)
    (ReachTask, False, "measured"),
    (ReachTask, True, "measured"),
    (PickTask, False, "measured"),
    (TraceTask, False, "measured"),
    (ReachTask, False, "commanded"),
    (PickTask, False, "commanded"),
    (PickTask, False, "mixed"),
]


@pytest.mark.parametrize(("task_cls", "goal_mode", "feedback"), CASES)
def test_observe_is_the_sensor_models_goal_rule_and_builder(
    task_cls: type, goal_mode: bool, feedback: str
) -> None:
    """``SensorModel.read`` (commanded readings: the echo of what was sent) → ``occlude`` →
    ``delay``, the task's goal (pick: ``judge_holding`` by the gripper's reading kind, then the
    grasp-aware ``cube_estimate``), ``command_readings`` and ``ObservationBuilder.build``,
    against one call."""
    spec = FEEDBACK[feedback]
    assert spec.gripper is not None
    grip_kind = spec.gripper.feedback
    task = task_cls()
    n_j = SPEC.n_joints
    n_r = n_j + (1 if task.uses_gripper else 0)
    n_act = n_r
    builder = ObservationBuilder(task.obs_fields(n_r, n_act, goal_mode))
    layout = np.array(
        [(fused.FIELDS[f.name], f.start, f.stop - f.start) for f in builder.layout()],
        dtype=np.int64,
    )
    g = SPEC.gripper
    assert g is not None
    no_contacts = np.zeros((1, 4), dtype=np.int32)[:, ::2]
    no_ids, no_prm = np.zeros(0, dtype=np.int32), np.zeros(0)
    rng = np.random.default_rng([len(task.name), goal_mode, len(feedback)])
    dt = 0.05
    held_counts = {"near": 0, "hidden": 0}
    for _episode in range(12):
        ref, fast = _sensor_pair(rng, n_r, spec, dt)
        r_ref, r_fast = np.random.default_rng(3), np.random.default_rng(3)
        prm = np.zeros(fused.N_PRM + 2 * n_r)
        fused.put_camera(prm, fast)
        fused.put_sensing(prm, fast)
        prm[fused.P_DT] = dt
        prm[fused.P_GRIP_CLOSED : fused.P_GRIP_READ + 1] = (
            g.closed_rad, g.open_rad, g.max_gap_m, float(task.uses_gripper),
        )  # fmt: skip
        prm[fused.P_HOLD_MARGIN], prm[fused.P_BLIND_CAP] = HOLD_MARGIN_RAD, BLIND_CAP_S
        prm[fused.P_HOLD_NEAR] = task.grasp_near_m
        prm[fused.P_HELD_AWAY] = task.held_away_m
        prm[fused.P_HOLD_RULE] = fused.HOLD_RULES[grip_kind]
        prm[fused.P_SIGN0 : fused.P_SIGN2 + 1] = [j.sign for j in SPEC.joints[:3]]
        L = SPEC.links
        prm[fused.P_UPPER : fused.P_TOOL_DOWN + 1] = (
            L.upper_arm_m, L.forearm_m, L.tool_forward_m, L.base_height_m, L.tool_down_m,
        )  # fmt: skip
        prm[fused.P_GOAL_RULE] = fused.GOAL_RULES[task.goal_rule]
        prm[fused.P_OCCLUDABLE] = task.occludable
        delay = fast.delay_steps
        ints = fused.observe_ints(np.arange(n_r), layout)
        ints[fused.S_DELAY] = delay
        fused.RngBinding().bind(ints, r_fast)  # the occlusion draws, as ``occlude`` makes them
        mem = fused.observe_memory(1, n_r, delay)
        goals = fused.observe_goals(mem, 1)
        aux = rng.uniform(-0.2, 0.2, (2, 3))
        was_held, grip_rad, carried = False, g.open_rad, False
        for _ in range(40):
            qpos = rng.uniform(-1.5, 1.5, n_r + 2)
            if task.uses_gripper:
                qpos[n_j] = rng.uniform(-0.002, g.max_gap_m / 2 + 0.002)
            tool = rng.uniform(-0.2, 0.3, 3)
            # near the tool half the time, so occlusion hides it
            point = tool + rng.normal(0, 0.015, 3) if rng.random() < 0.6 else rng.uniform(0, 0.3, 3)
            targets = rng.uniform(-1.5, 1.5, n_r)
            if task.uses_gripper:  # kept for a few periods: its echo slews there, then stays
                grip_rad = (
                    grip_rad if rng.random() < 0.8 else rng.choice([g.closed_rad, g.open_rad])
                )
                targets[n_j] = grip_rad
            # what the safety filter let through: the targets, or a step short of them
            sent = targets + (rng.uniform(-0.3, 0.3, n_r) if rng.random() < 0.3 else 0.0)
            prev_action = rng.uniform(-1, 1, n_act).astype(rng.choice([np.float32, np.float64]))
            true_a, true_d = rng.uniform(-0.3, 0.3, 3), rng.uniform(-0.3, 0.3, 3)

            # the reference: the numpy models as the env composed them
            q = qpos[:n_r].copy()
            if task.uses_gripper:
                q[n_j] = finger_m_to_gripper_rad(SPEC, float(qpos[n_j]))
            joints, est = ref.read(q, np.stack([tool, point]), r_ref, sent_rad=sent)
            blind = np.zeros(1)
            if task.occludable:
                held, blind_n = ref.occlude(est[1:], tool, point[None], r_ref)
                est, blind = np.concatenate([est[:1], held]), blind_n * dt
            if ref.delay_steps:
                joints, est, blind = ref.delay(joints, est, blind)
            ee, obj = est[0], est[1]
            grasp = False
            if task.uses_gripper:
                grasp = judge_holding(spec, targets, joints, ee, obj, float(blind[0]), was_held)
                if grasp and grip_kind == "commanded":
                    held_counts["hidden" if blind[0] > 0 and was_held else "near"] += 1
                was_held = grasp
            obj, carried = cube_estimate(obj, ee, blind[0], grasp, carried)
            achieved, desired = (ee, obj) if task.goal_rule == "tool_to_point" else (obj, aux[0])
            readings = {
                "joint_pos": joints,
                "joint_target": targets[:n_r],
                "ee_pos": ee,
                "goal_pos": desired,
                "goal_delta": desired - achieved,
                "prev_action": prev_action,
                "goal_vel": aux[1],
                **cube_readings(ee, obj, float(blind[0])),
                **command_readings(spec, targets, desired),
            }
            want = builder.build(readings)
            diff = true_a - true_d

            noise = fast.draw(2, r_fast)
            obs = np.empty(builder.size, dtype=np.float32)
            d, shaped = fused.observe(
                qpos, tool, point[None], prm, ints, noise, mem, targets, sent, prev_action, aux,
                true_a, true_d, obs, no_contacts, no_ids, no_prm,
            )  # fmt: skip
            np.testing.assert_array_equal(obs, want)
            np.testing.assert_array_equal(goals, np.stack([achieved, desired]))
            # numpy's ``@`` runs BLAS (FMA kernels on some CPUs): one rounding apart at most
            assert d == pytest.approx(np.sqrt(diff @ diff), rel=1e-14, abs=1e-15)
            assert shaped == 0.0  # no shaping rule in prm
            # both generators made the same draws: the kernel's through the bit generator
            assert r_fast.bit_generator.state == r_ref.bit_generator.state
    if task.uses_gripper and grip_kind == "commanded":  # both ways to hold were met
        assert min(held_counts.values()) > 0, held_counts


def test_rng_binding_is_not_copied() -> None:
    """A bound generator's addresses belong to one process and one object: a deep copy or an
    unpickled binding starts unbound, so its env rebinds to its own generator."""
    binding, state = fused.RngBinding(), np.zeros(fused.N_STATE, dtype=np.int64)
    rng = np.random.default_rng(0)
    binding.bind(state, rng)
    assert binding.rng is rng and state[fused.S_RNG_STATE] != 0
    assert copy.deepcopy(binding).rng is None
    assert pickle.loads(pickle.dumps(binding)).rng is None


def test_pick_shaping_is_the_grasp_check_and_the_lift() -> None:
    """The compiled shaping against ``is_grasped`` and ``lift_m`` on real contacts: held starts
    (both fingers on the cube), default starts, and random steps that let go and touch again.
    The step's shaping (``grasp_reach`` in the observation call, the contact list only when
    every finger is near the cube) is the same value; it skips the list only without a grasp."""
    env = envs.make("Sim2Real/Arm3Pick-v0")
    u: Any = env.unwrapped
    rng = np.random.default_rng(5)
    grasped = near = far = 0
    try:
        for episode in range(6):
            env.reset(seed=episode, options={"start": "held" if episode < 4 else "default"})
            for _ in range(30):
                a = rng.uniform(-1, 1, 4).astype(np.float32)
                a[3] = -1.0 if rng.random() < 0.8 else a[3]
                _, reward, _, _, info = env.step(a)
                d = info["distance_m"]
                assert reward == float(
                    u._reward_fn(d, d < u.task.success_threshold_m)
                ) + u.task.shaping(u)
                v = u.ee_position() - u.task.cube_position(u)
                want = -2.0 * float(np.linalg.norm(v))
                if u.task.is_grasped(u):
                    grasped += 1
                    want = want + 0.5 + 10.0 * u.task.lift_m(u)
                assert u.task.shaping(u) == pytest.approx(
                    want, rel=1e-14, abs=1e-15
                )  # np.linalg.norm: BLAS
                # the arm's version (``finetune.ArmEnv``), fed what it would perceive: it pays
                # the grasp only with the tool at the cube (a grasp by the fingertips' far ends
                # is one the arm cannot tell from a gripper closing in empty air)
                apart = float(np.linalg.norm(v))
                want_arm = want if apart < GRASP_NEAR_M else -2.0 * apart
                assert percept_shaping(
                    u.ee_position(), u.task.cube_position(u), u.task.rest_z_m,
                    u.task.is_grasped(u),
                ) == pytest.approx(want_arm, abs=1e-12)  # fmt: skip
                gated = fused.grasp_reach(
                    u.ee_position(), u.task.cube_position(u), u.data.geom_xpos,
                    u.task.shaping_ids, u.task.shaping_prm,
                )  # fmt: skip
                if np.isnan(gated):
                    near += 1
                else:
                    far += 1
                    assert gated == pytest.approx(want, rel=1e-14, abs=1e-15)
                    assert not u.task.is_grasped(u)
    finally:
        env.close()
    assert grasped > 10  # the grasp branch was exercised
    assert near > grasped and far > 10  # and both sides of the contact-list gate


def test_the_arm_pays_no_grasp_bonus_for_a_gripper_closing_in_empty_air() -> None:
    """On the arm "holding" is the gripper reading open while commanded closed: true for the few
    periods a gripper closing on nothing takes. Only at the cube is that a grasp."""
    tool, rest_z = np.array([0.15, 0.0, 0.05]), 0.0125
    cube = np.array([0.15, 0.0, 0.0125])  # 3.75 cm under the tool
    assert percept_shaping(tool, cube, rest_z, True) == percept_shaping(tool, cube, rest_z, False)
    held = tool + (0.0, 0.0, -0.005)  # in the fingers, lifted 3.25 cm
    assert percept_shaping(tool, held, rest_z, True) == pytest.approx(
        -2.0 * 0.005 + 0.5 + 10.0 * (held[2] - rest_z)
    )
