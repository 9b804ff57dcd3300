"""Sensing DR: joint readings as a servo bus reports them, positions as the stereo rig sees them.

Stereo error is anisotropic: for a point at depth Z, lateral σ = Z·σ_px/f and depth
σ_z = Z²·σ_d/(f·B) with disparity noise σ_d = √2·σ_px (NOTES: 1.3–2.2 mm at 0.5 m for 0.2 px).
The noise is drawn in the camera frame and rotated into the base frame.

Objects the gripper can hide (the pick cube) also drop out: hidden when the tool is within
``occlusion_radius_m`` of them (with probability ``occlusion_prob`` per period: the fingers and
the palm cover its markers during a grasp, which is the normal case) or at random
(``point_dropout_prob``: glare, motion blur). A hidden object's estimate holds its last value, as
the deploy loop's still-object Kalman tracker coasts, and the time since it was last seen is
reported: what ``calibration.cube.StereoCubeTracker`` gives the deploy loop.

A reading is *measured* (a sensor on the horn: the true joint through bias, noise and
quantisation) or *commanded* (``hardware.spec.FEEDBACK_KINDS``: a board driving a bare PWM servo
can only echo the pulse it sent). A commanded reading is that echo: the command the host sent
(after its safety filter), slewed as the firmware slews its output pulse (at most
``slew_rad_per_step`` per period: the spec's speed times the period; the firmware's µs rate is
its floor), in the quantisation of the reading's units, without the joint-calibration bias (the
host converts the echoed pulse back with the very map it sent with: a calibration error moves the
horn, which the kinematics DR models, never the echo) and without noise: a digital echo is exact. It shares the delay line: the host reads every position
in one state frame. It cannot show lag, droop, a stall or a grasped cube.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping

import numpy as np

from sim2real.randomization.base import (
    DirectKey,
    ModelIds,
    NoiseBuffer,
    Params,
    draw_keys,
    round_steps,
)
from sim2real.randomization.config import Range


def sample(rng: np.random.Generator, ranges: Mapping[str, Range], ids: ModelIds) -> Params:
    """The sensor models' parameters for one episode (``direct_keys``)."""
    return draw_keys(direct_keys(ids), rng, ranges)


def direct_keys(ids: ModelIds) -> list[DirectKey]:
    """The sensor models' draws, in their order."""
    return [
        ("joint_noise_rad", None, float),
        ("joint_bias_rad", len(ids.arm_dofs), None),
        ("stereo_pixel_noise_px", None, float),
        ("position_bias_m", 3, None),
        ("obs_delay_steps", None, round_steps),
        ("point_dropout_prob", None, float),
        ("occlusion_radius_m", None, float),
        ("occlusion_prob", None, float),
    ]


class SensorModel:
    """Applies per-episode sensing parameters to true joint angles and point positions.

    ``commanded`` (n,) bool: readings that echo the sent command (None: all measured), each
    moving at most ``slew_rad_per_step`` (n,) per period towards it (the board's output slew)."""

    def __init__(
        self,
        n_joints: int,
        resolution_rad: float,
        base_R_cam: np.ndarray,
        base_p_cam_m: np.ndarray,
        focal_px: float,
        baseline_m: float,
        commanded: np.ndarray | None = None,
        slew_rad_per_step: np.ndarray | None = None,
    ) -> None:
        self._n = n_joints
        self.commanded = np.zeros(n_joints, dtype=bool)
        self.slew_rad_per_step = np.zeros(n_joints)
        if commanded is not None:
            self.commanded = np.array(commanded, dtype=bool).reshape(-1)
            if self.commanded.shape != (n_joints,):
                raise ValueError(f"commanded must have shape ({n_joints},), got {commanded!r}")
            slew = np.zeros(n_joints) if slew_rad_per_step is None else slew_rad_per_step
            self.slew_rad_per_step = np.array(slew, dtype=float).reshape(-1)
            ok = self.slew_rad_per_step.shape == (n_joints,) and bool(
                np.all(self.slew_rad_per_step[self.commanded] > 0)
            )
            if not ok:
                raise ValueError(
                    "slew_rad_per_step must give every commanded reading a step > 0, got "
                    f"{slew_rad_per_step!r}"
                )
        self.any_commanded = bool(self.commanded.any())
        self._echo: np.ndarray | None = None  # the board's output pulse (rad) per reading
        self.resolution_rad = resolution_rad
        self.inv_resolution = 1.0 / resolution_rad if resolution_rad > 0 else 0.0
        self.base_R_cam = np.asarray(
            base_R_cam, dtype=float
        )  # OpenCV camera axes in the base frame
        self.cam_p_m = np.asarray(base_p_cam_m, dtype=float)
        self.cam_z = self.base_R_cam[:, 2].copy()
        self._f = focal_px
        self._B = baseline_m
        self.configure(
            {
                "joint_noise_rad": 0.0,
                "joint_bias_rad": np.zeros(n_joints),
                "stereo_pixel_noise_px": 0.0,
                "position_bias_m": np.zeros(3),
                "obs_delay_steps": 0,
                "point_dropout_prob": 0.0,
                "occlusion_radius_m": 0.0,
                "occlusion_prob": 0.0,
            }
        )
        self._history: deque[tuple[np.ndarray, ...]] = deque()
        self._noise: NoiseBuffer | None = None
        self._last_seen: np.ndarray | None = None
        self._blind_steps = np.zeros(0)

    def configure(self, params: Params) -> None:
        self.joint_noise = float(params["joint_noise_rad"])
        bias = np.asarray(params["joint_bias_rad"], dtype=float)
        self.joint_bias = np.zeros(self._n)  # the gripper reading (if any) gets no bias
        self.joint_bias[: min(len(bias), self._n)] = bias[: self._n]
        self.px_noise = float(params["stereo_pixel_noise_px"])
        self.pos_bias = np.asarray(params["position_bias_m"], dtype=float)
        self.delay_steps = int(params["obs_delay_steps"])
        self.dropout_prob = float(params.get("point_dropout_prob", 0.0))
        self.occlusion_radius_m = float(params.get("occlusion_radius_m", 0.0))
        self.occlusion_prob = float(params.get("occlusion_prob", 0.0))
        px = self.px_noise
        self.sigma_coef = np.array(
            [px / self._f, px / self._f, np.sqrt(2.0) * px / (self._f * self._B)]
        )
        self._history = deque(maxlen=self.delay_steps + 1)

    def read_joints(self, q_rad: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        out = q_rad + self.joint_bias
        if self.joint_noise > 0:
            out += rng.normal(0.0, self.joint_noise, self._n)
        if self.resolution_rad > 0:
            out = np.rint(out * self.inv_resolution) * self.resolution_rad
        return out

    def stereo_sigma_m(self, base_p_m: np.ndarray) -> np.ndarray:
        """Per-axis σ (k, 3) in the camera frame for points (k, 3): lateral, lateral, depth."""
        depth = np.maximum((np.atleast_2d(base_p_m) - self.cam_p_m) @ self.base_R_cam[:, 2], 1e-3)
        lateral = depth * self.px_noise / self._f
        axial = depth * depth * np.sqrt(2.0) * self.px_noise / (self._f * self._B)
        return np.stack([lateral, lateral, axial], axis=1)

    def read_points(self, points_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noisy estimates (k, 3) of k points (k, 3) in the base frame (hot path)."""
        out = points_m + self.pos_bias
        if self.px_noise > 0:
            depth = (points_m - self.cam_p_m) @ self.cam_z  # (k,)
            # σ per camera axis = depth · (px/f) laterally, depth² · √2·px/(f·B) along z.
            scale = np.multiply.outer(depth, self.sigma_coef)
            scale[:, 2] *= depth
            out += (rng.standard_normal(points_m.shape) * scale) @ self.base_R_cam.T
        return out

    def draw(self, k: int, rng: np.random.Generator) -> np.ndarray:
        """This step's standard normals for the joints and k points (n + 3k,): one RNG call per
        block of steps. ``read`` uses them, and so does the envs' compiled step."""
        return self.noise_buffer(k).take(rng)

    def noise_buffer(self, k: int) -> NoiseBuffer:
        """The buffer ``draw`` takes from for k points (``reset`` clears it; it stays the same
        object while k does): a caller on the hot path keeps it and calls ``take``."""
        dim = self._n + 3 * k
        if self._noise is None or self._noise.dim != dim:
            self._noise = NoiseBuffer(dim)
        return self._noise

    def echo(self, sent_rad: np.ndarray) -> np.ndarray:
        """The board's output pulses (n,) after one more period of slewing towards ``sent_rad``
        (n,), as the firmware's limiter: the target once within a step, else one step towards
        it. The first call after ``reset`` starts at ``sent_rad`` (attached at the start
        pulse). Entries of measured readings are not used."""
        sent = np.asarray(sent_rad, dtype=float)
        if self._echo is None:
            self._echo = sent.copy()
            return self._echo.copy()
        d = sent - self._echo
        step = self.slew_rad_per_step
        moved = np.where(d > 0, self._echo + step, self._echo - step)
        self._echo = np.where(np.abs(d) <= step, sent, moved)
        return self._echo.copy()

    def read(
        self,
        q_rad: np.ndarray,
        points_m: np.ndarray,
        rng: np.random.Generator,
        sent_rad: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Joint readings (n,) and point estimates (k, 3) from one block of pre-drawn noise:
        the reference the arm envs' compiled step (``sim2real.envs.fused.observe``) is held to
        (``tests/sim2real/envs/test_fused.py``). ``read_joints``/``read_points``: per-call draws.
        ``sent_rad`` (n,): what the host last sent, which commanded readings echo (``echo``);
        the noise block is drawn whole either way, so the generator moves alike."""
        n, k = self._n, len(points_m)
        z = self.draw(k, rng)
        if self.any_commanded:
            if sent_rad is None:
                raise ValueError("commanded readings need sent_rad, the command they echo")
            q_rad = np.where(self.commanded, self.echo(sent_rad[:n]), q_rad)
        bias = (
            np.where(self.commanded, 0.0, self.joint_bias)
            if self.any_commanded
            else self.joint_bias
        )
        joints = q_rad + bias
        if self.joint_noise > 0:
            noisy = joints + self.joint_noise * z[:n]
            joints = np.where(self.commanded, joints, noisy) if self.any_commanded else noisy
        if self.resolution_rad > 0:
            joints = np.rint(joints * self.inv_resolution) * self.resolution_rad
        points = points_m + self.pos_bias
        if self.px_noise > 0:
            depth = (points_m - self.cam_p_m) @ self.cam_z
            scale = np.multiply.outer(depth, self.sigma_coef)
            scale[:, 2] *= depth
            points += (z[n:].reshape(k, 3) * scale) @ self.base_R_cam.T
        return joints, points

    def occlude(
        self,
        estimates_m: np.ndarray,
        true_tool_m: np.ndarray,
        true_points_m: np.ndarray,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Estimates (k, 3) with hidden objects held at their last seen estimate, and the number
        of periods (k,) since each was last seen. The first call after ``reset`` always sees."""
        k = len(estimates_m)
        if self._last_seen is None or len(self._last_seen) != k:
            self._last_seen = np.array(estimates_m, dtype=float)
            self._blind_steps = np.zeros(k)
            return self._last_seen.copy(), self._blind_steps.copy()
        u = rng.random((2, k))
        d = true_points_m - true_tool_m  # np.linalg.norm(d, axis=1), without its overhead
        near = np.sqrt(np.add.reduce(d * d, axis=1)) < self.occlusion_radius_m
        hidden = (near & (u[0] < self.occlusion_prob)) | (u[1] < self.dropout_prob)
        self._last_seen[~hidden] = estimates_m[~hidden]
        self._blind_steps = np.where(hidden, self._blind_steps + 1, 0.0)
        return self._last_seen.copy(), self._blind_steps.copy()

    def delay(self, *readings: np.ndarray) -> tuple[np.ndarray, ...]:
        """Observation delay: returns the readings from ``delay_steps`` calls ago."""
        if self.delay_steps == 0:
            return readings
        self._history.append(readings)
        return self._history[0]

    def reset(self) -> None:
        self._history.clear()
        self._last_seen = None
        self._echo = None
        if self._noise is not None:
            self._noise.clear()
