"""The arm envs' per-step layers compiled (numba): action decoding, the servo, the sensor models,
the observation and the true distance, one call each side of the physics.

Why: the numpy layers cost ~100 calls on 3-element arrays per step, more than half the physics
again (docs/studies/sim-speed.md, "The step path"). Each kernel here does the *same* floating-point
operations in the same order as its numpy reference, so the envs return the same bits
(``tests/sim2real/envs/test_step_pin.py``); ``tests/sim2real/envs/test_fused.py`` holds every
kernel equal to its reference on random inputs:

* ``decode`` ≡ ``observation.ActionDecoder.decode``;
* ``actuate`` ≡ ``actuation.ServoActuation`` (``hardware.servo_model.StepServo``), on its state;
* ``command`` ≡ ``decode`` then ``actuate`` (the step's action side when no safety filter sits
  between them);
* ``observe`` ≡ ``randomization.sensing.SensorModel`` (``read`` → ``occlude`` → ``delay``; a
  commanded reading is the echo of what was sent, ``SensorModel.echo``), the tasks' goal rules
  (pick: ``pick.judge_holding`` by the gripper's reading kind, then ``pick.cube_estimate``) and
  ``observation.command_readings`` / ``ObservationBuilder.build``, and a task's compiled shaping
  (pick: ``grasp_reach``, then ``grasp_shaping`` ≡ ``PickTask``'s ``is_grasped`` and ``lift_m``
  where the contact list decides).

Per call, numba unboxes every array argument (about 0.05 µs each): the kernels take a few
packed arrays (``prm``, ``ints``, ``mem``, ``cmd``) rather than one per quantity.

numpy hands 3-element dot products to OpenBLAS, whose kernels fuse multiply-adds: ``_dot3`` and
friends reproduce those roundings with explicit FMAs. Random draws stay in numpy's Generator on
the Python side, in the order and number the reference draws them, and come in as arrays; the
occlusion's uniform draws are made in ``observe`` from the env's generator's own bit generator
(``RngBinding``: the same calls ``Generator.random`` makes, so the same values and state).

Kernels are cached on disk (``cache=True``) so a test process loads them instead of compiling;
where no cache directory is writable they compile per process.
"""

from __future__ import annotations

import ctypes
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numba
import numpy as np
from llvmlite import ir  # type: ignore[import-untyped]
from numba.core import types
from numba.extending import intrinsic

if TYPE_CHECKING:
    from sim2real.randomization.sensing import SensorModel


def _jit(fn: Callable[..., Any]) -> Any:
    try:
        return numba.njit(cache=True)(fn)
    except RuntimeError:  # no writable cache directory: compile in this process
        return numba.njit(cache=False)(fn)


def _fma_typing(typingctx: Any, a: Any, b: Any, c: Any) -> Any:
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        return builder.fma(*args)

    return sig, codegen


# fma(a, b, c) = a·b + c with one rounding (LLVM's fma), as OpenBLAS's kernels compute it
_fma: Any = intrinsic(_fma_typing)


def _next_double_typing(typingctx: Any, next_double: Any, state: Any) -> Any:
    sig = types.float64(types.int64, types.int64)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        void_p = ir.IntType(8).as_pointer()
        fn_t = ir.FunctionType(ir.DoubleType(), [void_p])
        fn = builder.inttoptr(args[0], fn_t.as_pointer())
        return builder.call(fn, [builder.inttoptr(args[1], void_p)])

    return sig, codegen


# next_double(state): a numpy bit generator's next double in [0, 1), through its C interface
# (``BitGenerator.ctypes``; numpy's own way to draw from it in numba), addresses as integers so
# the cached kernels hold no process's addresses
_next_double: Any = intrinsic(_next_double_typing)


class RngBinding:
    """Which generator ``observe`` draws from: ``bind`` puts its bit generator's
    ``next_double`` and state addresses into ``observe``'s ``state``. ``Generator.random`` fills
    its output with exactly these calls, so the kernel's draws are ``rng.random``'s and leave
    ``rng`` where they would. The binding keeps ``rng`` (so the addresses) alive; the owner
    rebinds when its generator changes (``rng is not binding.rng``). A copy or an unpickled one
    starts unbound: addresses belong to one process and one generator object. The kernel does
    not take the generator's lock: like the env, not for two threads at once."""

    def __init__(self) -> None:
        self.rng: np.random.Generator | None = None

    def bind(self, state: np.ndarray, rng: np.random.Generator) -> None:
        iface = rng.bit_generator.ctypes
        state[S_RNG_NEXT] = ctypes.cast(iface.next_double, ctypes.c_void_p).value or 0
        state[S_RNG_STATE] = iface.state_address
        self.rng = rng

    def __deepcopy__(self, memo: dict[int, Any]) -> RngBinding:
        return RngBinding()

    def __reduce__(self) -> tuple[type[RngBinding], tuple[()]]:
        return (RngBinding, ())


@_jit
def _dot3(x0: float, x1: float, x2: float, y0: float, y1: float, y2: float) -> float:
    """``x @ y`` of two 3-vectors as numpy computes it (OpenBLAS ddot)."""
    return _fma(x2, y2, _fma(x1, y1, x0 * y0))


@_jit
def _gemv3(a0: float, a1: float, a2: float, v0: float, v1: float, v2: float) -> float:
    """One row of ``A @ v`` for A (2, 3), v (3,) as numpy computes it (OpenBLAS dgemv)."""
    return _fma(a2, v2, _fma(a0, v0, a1 * v1))


@_jit
def _clip(x: float, lo: float, hi: float) -> float:
    """``min(max(x, lo), hi)`` with numpy's and Python's NaN and signed-zero behaviour."""
    if lo > x:
        x = lo
    if x > hi:
        x = hi
    return x


# ---- action side ------------------------------------------------------------------------------
@_jit
def decode(
    action: np.ndarray,
    a_out: np.ndarray,
    previous_rad: np.ndarray,
    targets_out: np.ndarray,
    lower_rad: np.ndarray,
    upper_rad: np.ndarray,
    max_delta: Any,
    grip: np.ndarray,
) -> None:
    """Clip the action into ``a_out`` (the action's dtype: a float32 action scales in float32,
    as numpy does) and write the new actuator targets. ``grip``: [use, closed_rad, open_rad]."""
    for i in range(action.shape[0]):
        a_out[i] = _clip(action[i], -1.0, 1.0)
    for i in range(previous_rad.shape[0]):
        targets_out[i] = previous_rad[i]
    n = lower_rad.shape[0]
    for i in range(n):
        targets_out[i] = _clip(targets_out[i] + a_out[i] * max_delta, lower_rad[i], upper_rad[i])
    if grip[0] > 0.0:
        targets_out[n] = grip[1] + (np.float64(a_out[n]) + 1.0) / 2.0 * (grip[2] - grip[1])


@_jit
def actuate(
    sent_rad: np.ndarray,
    noise: np.ndarray,
    noise_rad: float,
    servo: np.ndarray,
    applied_rad: np.ndarray,
    queue_rad: np.ndarray,
    head: np.ndarray,
    ctrl: np.ndarray,
    grip: np.ndarray,
) -> None:
    """The servo's actuator targets for this step into ``ctrl`` (MuJoCo's), ``StepServo``'s state
    updated in place. ``servo``: [max_step_rad, deadband_rad, quantum_rad, per_quantum];
    ``grip``: [has_gripper, closed_rad, open_rad, max_gap_m]: the finger command from the
    gripper target (``model.gripper_rad_to_finger_m``)."""
    n = applied_rad.shape[0]
    latency = queue_rad.shape[0]
    max_step, deadband, quantum, per_quantum = servo[0], servo[1], servo[2], servo[3]
    h = head[0]
    for i in range(n):
        cmd = sent_rad[i]
        if noise_rad > 0:
            cmd = cmd + noise_rad * noise[i]
        if latency:
            due = queue_rad[h, i]
            queue_rad[h, i] = cmd
            cmd = due
        delta = cmd - applied_rad[i]
        if deadband > 0:
            delta = delta * (1.0 if abs(delta) >= deadband else 0.0)
        if delta > max_step:  # np.minimum, then np.maximum: NaN passes, as there
            delta = max_step
        if -max_step > delta:
            delta = -max_step
        out = applied_rad[i] + delta
        if quantum > 0:
            out = np.rint(out * per_quantum) * quantum
        applied_rad[i] = out
        ctrl[i] = out
    if latency:
        head[0] = (h + 1) % latency
    if grip[0] > 0.0:
        frac = _clip((sent_rad[sent_rad.shape[0] - 1] - grip[1]) / (grip[2] - grip[1]), 0.0, 1.0)
        ctrl[n] = frac * grip[3] / 2


# Slots of ``command``'s ``cmd`` array (float64) after its 2n joint limits (lower, then upper):
# ``decode``'s ``grip``, ``actuate``'s ``servo`` and ``grip``.
C_DECODE_GRIP, C_SERVO, C_CTRL_GRIP, N_CMD = 0, 3, 7, 11


@_jit
def command(
    action: np.ndarray,
    a_out: np.ndarray,
    previous_rad: np.ndarray,
    targets_out: np.ndarray,
    max_delta: Any,
    cmd: np.ndarray,
    noise: np.ndarray,
    noise_rad: float,
    applied_rad: np.ndarray,
    queue_rad: np.ndarray,
    head: np.ndarray,
    ctrl: np.ndarray,
) -> None:
    """``decode``, then ``actuate`` on the decoded targets: the step's action side in one call
    (one dispatch and fewer arrays to unbox than two) when no safety filter sits between them.
    ``cmd``: the n joints' lower and upper limits, then the ``C_*`` slots."""
    n = applied_rad.shape[0]
    o = 2 * n
    decode(
        action, a_out, previous_rad, targets_out, cmd[:n], cmd[n:o], max_delta,
        cmd[o + C_DECODE_GRIP : o + C_SERVO],
    )  # fmt: skip
    actuate(
        targets_out, noise, noise_rad, cmd[o + C_SERVO : o + C_CTRL_GRIP], applied_rad,
        queue_rad, head, ctrl, cmd[o + C_CTRL_GRIP : o + N_CMD],
    )  # fmt: skip


# ---- observation side -------------------------------------------------------------------------
# Parameter slots of ``observe``'s ``prm`` (float64) and ``state`` (int64) arrays.
P_JOINT_NOISE, P_RESOLUTION, P_INV_RESOLUTION, P_PX_NOISE = 0, 1, 2, 3
P_OCC_RADIUS, P_OCC_PROB, P_DROPOUT, P_DT = 4, 5, 6, 7
P_GRIP_CLOSED, P_GRIP_OPEN, P_GRIP_GAP, P_GRIP_READ = 8, 9, 10, 11
P_HOLD_MARGIN, P_BLIND_CAP, P_SIGN0, P_SIGN1, P_SIGN2 = 12, 13, 14, 15, 16
P_UPPER, P_FORE, P_TOOL_FWD, P_BASE_H, P_TOOL_DOWN = 17, 18, 19, 20, 21
P_GOAL_RULE, P_OCCLUDABLE, P_SHAPING, P_HOLD_RULE, P_HOLD_NEAR = 22, 23, 24, 25, 26
P_HELD_AWAY = 27  # a sighting this far from the tool is not the object the fingers hold
# the sensor model's vectors: position bias, σ coefficients, camera position, its z axis and
# base_R_cam (row-major); then per joint reading its bias, then its echo's slew per period
# (``SensorModel.slew_rad_per_step``; 0.0: a measured reading), to the end
P_POS_BIAS, P_SIGMA, P_CAM_P, P_CAM_Z, P_CAM_R, P_JOINT_BIAS = 28, 31, 34, 37, 40, 49
N_PRM = P_JOINT_BIAS  # ``prm`` has N_PRM + 2 × (number of joint readings) slots
# ``state``: the delay line's length and count, whether the points were seen since the reset,
# the last period's grasp judgement (``HOLD_RULES["commanded"]``), and the generator the
# occlusion draws come from (``bind_rng``)
S_DELAY, S_COUNT, S_SEEN, S_HELD, S_RNG_NEXT, S_RNG_STATE, N_STATE = 0, 1, 2, 3, 4, 5, 7
S_CARRIED = 6  # the last period's object estimate was the tool (``pick.cube_estimate``)

# How a task's observed goal is formed (``Task.goal_rule``): (achieved, desired).
GOAL_RULES = {
    "tool_to_point": 0,  # the tool estimate, the first task point's estimate
    "object_to_goal": 1,  # the grasp-aware object estimate, the task's goal (``Task.obs_aux[0]``)
}
# How the grasp-aware estimate judges "holding" (``pick.HOLD_RULES``), by the gripper reading's
# kind: a measured gripper from its reading (blocked open while commanded closed); one that reads
# its command from the estimates (closed, the cube within ``P_HOLD_NEAR`` of the tool or hidden
# in fingers that held it the period before).
HOLD_RULES = {"measured": 0, "commanded": 1}
# A task's compiled shaping (``Task.shaping_rule``), from ``Task.shaping_ids``/``shaping_prm``.
SHAPING_RULES = {
    "none": 0,  # ``Task.shaping`` runs in Python (0 unless the task overrides it)
    "grasp_lift": 1,  # ``grasp_shaping``: ids [object geom, fingers...], prm the ``G_*`` slots
}
# Observation fields the kernel fills, by name (``ObsField.name``).
FIELDS = {
    "joint_pos": 0,
    "ee_pos": 1,
    "goal_pos": 2,
    "goal_delta": 3,
    "joint_target": 4,
    "target_ee_pos": 5,
    "target_goal_delta": 6,
    "prev_action": 7,
    "cube_pos": 8,  # the grasp-aware object estimate (``pick.cube_estimate``)
    "cube_delta": 9,
    "cube_blind_s": 10,
    "goal_vel": 11,  # ``Task.obs_aux[1]``
}


def put_camera(prm: np.ndarray, sensors: SensorModel) -> None:
    """The stereo rig's fixed pose (``SensorModel``'s camera) into ``observe``'s ``prm``."""
    prm[P_CAM_P : P_CAM_P + 3] = sensors.cam_p_m
    prm[P_CAM_Z : P_CAM_Z + 3] = sensors.cam_z
    prm[P_CAM_R : P_CAM_R + 9] = sensors.base_R_cam.reshape(-1)


def put_sensing(prm: np.ndarray, sensors: SensorModel) -> None:
    """An episode's sensing parameters (``SensorModel.configure``) into ``observe``'s ``prm``."""
    prm[P_JOINT_NOISE] = sensors.joint_noise
    prm[P_RESOLUTION] = sensors.resolution_rad
    prm[P_INV_RESOLUTION] = sensors.inv_resolution
    prm[P_PX_NOISE] = sensors.px_noise
    prm[P_OCC_RADIUS] = sensors.occlusion_radius_m
    prm[P_OCC_PROB] = sensors.occlusion_prob
    prm[P_DROPOUT] = sensors.dropout_prob
    prm[P_POS_BIAS : P_POS_BIAS + 3] = sensors.pos_bias
    prm[P_SIGMA : P_SIGMA + 3] = sensors.sigma_coef
    n = len(sensors.joint_bias)
    prm[P_JOINT_BIAS : P_JOINT_BIAS + n] = sensors.joint_bias
    prm[P_JOINT_BIAS + n : P_JOINT_BIAS + 2 * n] = np.where(
        sensors.commanded, sensors.slew_rad_per_step, 0.0
    )


@_jit
def _put(obs: np.ndarray, start: int, x0: float, x1: float, x2: float) -> None:
    obs[start] = np.float32(x0)
    obs[start + 1] = np.float32(x1)
    obs[start + 2] = np.float32(x2)


def observe_ints(qadr: np.ndarray, layout: np.ndarray) -> np.ndarray:
    """``observe``'s ``ints``: the ``S_*`` state slots (zero: ``state[S_DELAY]`` is set per
    episode), the readings' qpos addresses (joints, then the first finger's with a gripper
    reading) and the layout's rows (``FIELDS`` code, start, size), flat."""
    return np.concatenate([np.zeros(N_STATE), qadr, np.ravel(layout)]).astype(np.int64)


def observe_memory(k: int, n_readings: int, delay: int) -> np.ndarray:
    """``observe``'s ``mem`` for k task points and a delay line of ``delay`` steps: the last
    seen estimates (k, 3), the blind counts (k,), the goals (2, 3), the echoes of commanded
    readings (n_readings,), then the delay line's rows of readings (delay + 1, each: joints,
    points (k + 1, 3), blind times (k,)). Zeros: as after a reset."""
    return np.zeros(4 * k + 6 + n_readings + (delay + 1) * (n_readings + 3 * (k + 1) + k))


def observe_goals(mem: np.ndarray, k: int) -> np.ndarray:
    """The (2, 3) view of ``mem``'s goals (achieved, desired), which ``observe`` writes."""
    return mem[4 * k : 4 * k + 6].reshape(2, 3)


@_jit
def observe(
    qpos: np.ndarray,
    tool_m: np.ndarray,
    true_points_m: np.ndarray,
    prm: np.ndarray,
    ints: np.ndarray,
    noise: np.ndarray,
    mem: np.ndarray,
    targets_rad: np.ndarray,
    sent_rad: np.ndarray,
    prev_action: np.ndarray,
    aux: np.ndarray,
    true_achieved_m: np.ndarray,
    true_desired_m: np.ndarray,
    obs: np.ndarray,
    geom_xpos: np.ndarray,
    shaping_ids: np.ndarray,
    shaping_prm: np.ndarray,
) -> tuple[float, float]:
    """Sense, observe, and judge one step; returns the true achieved-to-desired distance and
    the task's compiled shaping (``prm[P_SHAPING]``, ``SHAPING_RULES``; 0.0 without one; NaN
    when it needs MuJoCo's contact list: ``grasp_reach``).

    ``prm``: ``N_PRM`` slots, then per reading its bias, then its echo's slew (0: measured).
    ``ints``: ``observe_ints`` (its ``S_*`` state advanced in place); ``mem``:
    ``observe_memory`` (in place). ``targets_rad``: the decoded targets (the observation's
    command side); ``sent_rad``: what the safety filter let through, which commanded readings
    echo (``SensorModel.echo``; the first call after a reset starts there).
    ``noise``: this step's standard normals (joints, then 3 per point: the tool, the task's).
    The occlusion draws, ``rng.random((2, k))``'s, come from the generator ``RngBinding`` put
    into ``ints`` (none on the first call after a reset, as ``SensorModel.occlude``).
    ``geom_xpos``: MuJoCo's geom positions, read by the shaping rule only.
    Few arguments on purpose: unboxing each costs about 0.05 µs a call.
    """
    n_r = (prm.shape[0] - N_PRM) // 2
    n_j = n_r - 1 if prm[P_GRIP_READ] > 0.0 else n_r
    k = true_points_m.shape[0]
    state = ints[:N_STATE]
    qadr = ints[N_STATE : N_STATE + n_r]
    layout = ints[N_STATE + n_r :]
    last_seen_m = mem[: 3 * k].reshape((k, 3))
    blind_steps = mem[3 * k : 4 * k]
    goals_out = mem[4 * k : 4 * k + 6].reshape((2, 3))
    echo = mem[4 * k + 6 : 4 * k + 6 + n_r]
    slew = prm[P_JOINT_BIAS + n_r : P_JOINT_BIAS + 2 * n_r]
    # the delay line's rows: this call's readings go straight into row ``slot``
    delay = state[S_DELAY]
    count = state[S_COUNT]
    state[S_COUNT] = count + 1
    rows = delay + 1
    row_size = n_r + 3 * (k + 1) + k
    line = mem[4 * k + 6 + n_r : 4 * k + 6 + n_r + rows * row_size].reshape((rows, row_size))
    slot = count % rows
    joints = line[slot, :n_r]
    points = line[slot, n_r : n_r + 3 * (k + 1)].reshape((k + 1, 3))
    blind = line[slot, n_r + 3 * (k + 1) :]
    # --- SensorModel.read: bias, noise, quantisation; stereo-shaped position noise
    jn, res, inv_res = prm[P_JOINT_NOISE], prm[P_RESOLUTION], prm[P_INV_RESOLUTION]
    for i in range(n_j):
        joints[i] = qpos[qadr[i]]
    if n_j < n_r:  # the gripper reading (``model.finger_m_to_gripper_rad``)
        closed, opened = prm[P_GRIP_CLOSED], prm[P_GRIP_OPEN]
        frac = _clip(2 * qpos[qadr[n_j]] / prm[P_GRIP_GAP], 0.0, 1.0)
        joints[n_j] = closed + frac * (opened - closed)
    for i in range(n_r):  # SensorModel.echo: a commanded reading is the slewed command
        if slew[i] > 0.0:
            if count == 0:
                echo[i] = sent_rad[i]
            else:
                d = sent_rad[i] - echo[i]
                if abs(d) <= slew[i]:
                    echo[i] = sent_rad[i]
                elif d > 0:
                    echo[i] = echo[i] + slew[i]
                else:
                    echo[i] = echo[i] - slew[i]
            joints[i] = echo[i]
    for i in range(n_r):
        v = joints[i] + prm[P_JOINT_BIAS + i] if slew[i] == 0.0 else joints[i] + 0.0
        if jn > 0 and slew[i] == 0.0:
            v = v + jn * noise[i]
        if res > 0:
            v = np.rint(v * inv_res) * res
        joints[i] = v
    px = prm[P_PX_NOISE]
    for r in range(k + 1):
        p = tool_m if r == 0 else true_points_m[r - 1]
        for c in range(3):
            points[r, c] = p[c] + prm[P_POS_BIAS + c]
        if px > 0:
            depth = _gemv3(
                p[0] - prm[P_CAM_P],
                p[1] - prm[P_CAM_P + 1],
                p[2] - prm[P_CAM_P + 2],
                prm[P_CAM_Z],
                prm[P_CAM_Z + 1],
                prm[P_CAM_Z + 2],
            )
            z = noise[n_r + 3 * r : n_r + 3 * r + 3]
            m0 = z[0] * (depth * prm[P_SIGMA])
            m1 = z[1] * (depth * prm[P_SIGMA + 1])
            m2 = z[2] * (depth * prm[P_SIGMA + 2] * depth)
            for c in range(3):
                R = prm[P_CAM_R + 3 * c : P_CAM_R + 3 * c + 3]
                points[r, c] = points[r, c] + _fma(m2, R[2], _fma(m1, R[1], m0 * R[0]))
    # --- SensorModel.occlude: objects the fingers hide hold their last estimate
    if prm[P_OCCLUDABLE] > 0.0:
        if state[S_SEEN] == 0:
            for p in range(k):
                for c in range(3):
                    last_seen_m[p, c] = points[p + 1, c]
                blind_steps[p] = 0.0
            state[S_SEEN] = 1
        else:
            uniforms = np.empty((2, k))  # rng.random((2, k)): row by row
            for i in range(2):
                for p in range(k):
                    uniforms[i, p] = _next_double(state[S_RNG_NEXT], state[S_RNG_STATE])
            for p in range(k):
                d0 = true_points_m[p, 0] - tool_m[0]
                d1 = true_points_m[p, 1] - tool_m[1]
                d2 = true_points_m[p, 2] - tool_m[2]
                near = math.sqrt(d0 * d0 + (d1 * d1 + d2 * d2)) < prm[P_OCC_RADIUS]
                hidden = (near and uniforms[0, p] < prm[P_OCC_PROB]) or (
                    uniforms[1, p] < prm[P_DROPOUT]
                )
                if hidden:
                    blind_steps[p] = blind_steps[p] + 1
                else:
                    for c in range(3):
                        last_seen_m[p, c] = points[p + 1, c]
                    blind_steps[p] = 0.0
        for p in range(k):
            for c in range(3):
                points[p + 1, c] = last_seen_m[p, c]
            blind[p] = blind_steps[p] * prm[P_DT]
    # --- SensorModel.delay: the readings of ``delay`` calls ago (the first call's until then)
    if delay > 0:
        out = (count - delay) % rows if count >= delay else 0
        joints = line[out, :n_r]
        points = line[out, n_r : n_r + 3 * (k + 1)].reshape((k + 1, 3))
        blind = line[out, n_r + 3 * (k + 1) :]
    # --- the task's goal rule (``pick.cube_estimate``: an unseen object in holding fingers
    # moves with the tool; ``pick.judge_holding``: by the gripper reading's kind)
    obj = points[1]
    if n_j < n_r and targets_rad.shape[0] > n_j:
        closed = prm[P_GRIP_CLOSED]
        span = prm[P_GRIP_OPEN] - closed
        commanded_closed = (targets_rad[n_j] - closed) / span < 0.25
        reading_open = (joints[n_j] - closed) * np.sign(span) > prm[P_HOLD_MARGIN]
        if prm[P_HOLD_RULE] == 0.0:  # measured: the fingers stopped open by something
            held = commanded_closed and reading_open
        else:  # commanded: closed, and the cube at the tool or hidden in holding fingers
            held = False
            if commanded_closed and not reading_open:
                if blind[0] > 0.0 and state[S_HELD] != 0:
                    held = True
                else:
                    h0 = obj[0] - points[0, 0]
                    h1 = obj[1] - points[0, 1]
                    h2 = obj[2] - points[0, 2]
                    held = math.sqrt(_dot3(h0, h1, h2, h0, h1, h2)) < prm[P_HOLD_NEAR]
            state[S_HELD] = 1 if held else 0
        carried = False
        if held:  # hidden in the fingers, or, carried, "seen" where the object in them is not
            a0 = obj[0] - points[0, 0]
            a1 = obj[1] - points[0, 1]
            a2 = obj[2] - points[0, 2]
            away = math.sqrt(_dot3(a0, a1, a2, a0, a1, a2)) > prm[P_HELD_AWAY]
            if blind[0] > 0.0 or (away and state[S_CARRIED] != 0):
                obj = points[0]
                carried = True
            else:
                carried = not away
        state[S_CARRIED] = 1 if carried else 0
    if prm[P_GOAL_RULE] == 0:
        achieved, desired = points[0], obj
    else:
        achieved, desired = obj, aux[0]
    # --- command_readings: where the last command puts the tool (the spec's FK)
    yaw = prm[P_SIGN0] * targets_rad[0]
    a1 = prm[P_SIGN1] * targets_rad[1]
    a12 = a1 + prm[P_SIGN2] * targets_rad[2]
    rr = prm[P_UPPER] * math.sin(a1) + prm[P_FORE] * math.cos(a12) + prm[P_TOOL_FWD]
    zz = prm[P_BASE_H] + prm[P_UPPER] * math.cos(a1) - prm[P_FORE] * math.sin(a12)
    zz -= prm[P_TOOL_DOWN]
    fk0, fk1, fk2 = rr * math.cos(yaw), rr * math.sin(yaw), zz
    # --- ObservationBuilder.build
    ee = points[0]
    for f in range(layout.shape[0] // 3):
        code, start, size = layout[3 * f], layout[3 * f + 1], layout[3 * f + 2]
        if code == 0:
            for i in range(size):
                obs[start + i] = np.float32(joints[i])
        elif code == 1:
            _put(obs, start, ee[0], ee[1], ee[2])
        elif code == 2:
            _put(obs, start, desired[0], desired[1], desired[2])
        elif code == 3:
            _put(
                obs,
                start,
                desired[0] - achieved[0],
                desired[1] - achieved[1],
                desired[2] - achieved[2],
            )
        elif code == 4:
            for i in range(size):
                obs[start + i] = np.float32(targets_rad[i])
        elif code == 5:
            _put(obs, start, fk0, fk1, fk2)
        elif code == 6:
            _put(obs, start, desired[0] - fk0, desired[1] - fk1, desired[2] - fk2)
        elif code == 7:
            for i in range(size):
                obs[start + i] = np.float32(prev_action[i])
        elif code == 8:
            _put(obs, start, obj[0], obj[1], obj[2])
        elif code == 9:
            _put(obs, start, obj[0] - ee[0], obj[1] - ee[1], obj[2] - ee[2])
        elif code == 10:
            obs[start] = np.float32(_clip(blind[0], 0.0, prm[P_BLIND_CAP]))
        else:
            _put(obs, start, aux[1, 0], aux[1, 1], aux[1, 2])
    for c in range(3):
        goals_out[0, c] = achieved[c]
        goals_out[1, c] = desired[c]
    x0 = true_achieved_m[0] - true_desired_m[0]
    x1 = true_achieved_m[1] - true_desired_m[1]
    x2 = true_achieved_m[2] - true_desired_m[2]
    shaped = 0.0
    if prm[P_SHAPING] == 1.0:  # the task's first point is the object it grasps
        shaped = grasp_reach(tool_m, true_points_m[0], geom_xpos, shaping_ids, shaping_prm)
    return math.sqrt(_dot3(x0, x1, x2, x0, x1, x2)), shaped


# Slots of ``grasp_shaping``'s ``prm``; then, for ``grasp_reach``, one contact reach per id
# (``geom_rbound + geom_margin``, m).
G_REST_Z, G_REACH_PER_M, G_BONUS, G_LIFT_PER_M, G_LIFT_CAP_M, N_GRASP_PRM = 0, 1, 2, 3, 4, 5


@_jit
def _approach(tool_m: np.ndarray, object_m: np.ndarray, per_m: float) -> float:
    """The approach term, ``-per_m · |tool − object|`` (the norm as numpy's ``ddot`` rounds)."""
    v0, v1, v2 = tool_m[0] - object_m[0], tool_m[1] - object_m[1], tool_m[2] - object_m[2]
    return -per_m * math.sqrt(_dot3(v0, v1, v2, v0, v1, v2))


@_jit
def grasp_reach(
    tool_m: np.ndarray,
    object_m: np.ndarray,
    geom_xpos: np.ndarray,
    ids: np.ndarray,
    prm: np.ndarray,
) -> float:
    """``grasp_shaping`` without the contact list where it cannot matter: when some finger is
    too far from the object to touch it (its and the object's bounding spheres, grown by their
    margins, apart: MuJoCo makes no contact then), there is no grasp and the shaping is the
    approach term, the same value ``grasp_shaping`` returns; otherwise NaN: the caller reads the
    contacts and calls ``grasp_shaping``. Reading the contact list costs more than this."""
    reach = _approach(tool_m, object_m, prm[G_REACH_PER_M])
    g = ids[0]
    for f in range(1, ids.shape[0]):
        h = ids[f]
        d0 = geom_xpos[h, 0] - geom_xpos[g, 0]
        d1 = geom_xpos[h, 1] - geom_xpos[g, 1]
        d2 = geom_xpos[h, 2] - geom_xpos[g, 2]
        apart = prm[N_GRASP_PRM] + prm[N_GRASP_PRM + f]
        # a relative and an absolute slack far above the rounding of either distance
        if math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) > apart * (1.0 + 1e-9) + 1e-9:
            return reach
    return math.nan


@_jit
def grasp_shaping(
    tool_m: np.ndarray,
    object_m: np.ndarray,
    contact_geoms: np.ndarray,
    ids: np.ndarray,
    prm: np.ndarray,
) -> float:
    """Pick's staged shaping (``PickTask.shaping``): approach, both fingers on the object, lift.
    ``contact_geoms`` (ncon, 2): MuJoCo's contact pairs; ``ids``: [object geom, finger geoms...];
    ``prm``: the ``G_*`` slots (the object's resting height, the weights, the lift cap)."""
    reach = _approach(tool_m, object_m, prm[G_REACH_PER_M])
    object_geom = ids[0]
    for f in range(1, ids.shape[0]):
        touching = False
        for c in range(contact_geoms.shape[0]):
            g1, g2 = contact_geoms[c, 0], contact_geoms[c, 1]
            if (g1 == object_geom and g2 == ids[f]) or (g2 == object_geom and g1 == ids[f]):
                touching = True
                break
        if not touching:
            return reach
    lift = _clip(object_m[2] - prm[G_REST_Z], 0.0, prm[G_LIFT_CAP_M])
    return reach + prm[G_BONUS] + prm[G_LIFT_PER_M] * lift
