"""Wiring for ``sim2real deploy``: one registry of backends, each building (arm, perception,
world) around the same loop. Everything opened is closed by one ExitStack, in reverse order."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hardware.arm import ArmBase
from hardware.errors import HardwareError
from hardware.spec import ArmSpec
from sim2real.deploy.loop import DeployLoop, DeployResult, LoopConfig, Percept, Perception, World
from sim2real.deploy.perception import OraclePerception, StereoFrameSource, StereoPerception
from sim2real.errors import ConfigError, UnknownNameError


@dataclass(frozen=True)
class DeployOptions:
    backend: str = "mock"
    protocol: str = "s2r"
    port: str | None = None
    baud: int | None = None
    joint_calibration: Path | None = None
    cameras: tuple[int, int] = (0, 1)
    stereo_calibration: Path | None = None
    base_T_left: np.ndarray | None = None  # noqa: N815 - frame names are part of the name
    dry_run: bool = False
    camera_timeout_s: float = 1.0
    camera_fails_after_frames: int | None = None  # mock fault injection
    emulator_options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise UnknownNameError("backend", self.backend, BACKENDS)
        if self.backend == "serial" and not self.port:
            raise ConfigError("--backend serial needs --port (for example /dev/ttyUSB0)")
        if self.dry_run and self.backend != "serial":
            raise ConfigError(f"--dry-run is for --backend serial, not {self.backend!r}")


Built = tuple[ArmBase, Perception, World]
Builder = Callable[[ArmSpec, DeployOptions, contextlib.ExitStack], Built]


def _build_sim(spec: ArmSpec, opts: DeployOptions, stack: contextlib.ExitStack) -> Built:
    from sim2real.deploy.sim_arm import SimArm
    from sim2real.deploy.worlds import SimWorld

    arm = SimArm(spec, clock="realtime")
    stack.enter_context(arm)

    def place(p: np.ndarray) -> None:
        arm.data.mocap_pos[0] = p

    world = SimWorld(spec, arm.tool_position, place)
    return arm, OraclePerception(arm.tool_position, lambda: world.target_m), world


def _build_mock(spec: ArmSpec, opts: DeployOptions, stack: contextlib.ExitStack) -> Built:
    from hardware.emulator.server import Emulator, EmulatorConfig
    from hardware.serial_arm import SerialArm
    from sim2real.deploy.virtual_cameras import VirtualStereoCameras, stereo_rig_of
    from sim2real.deploy.worlds import MockWorld

    emulator = Emulator(spec, opts.protocol, EmulatorConfig(**opts.emulator_options))
    stack.enter_context(emulator)
    cameras = VirtualStereoCameras(spec)
    stack.callback(cameras.close)
    rig, base_T_left = stereo_rig_of(cameras.rig)
    if opts.stereo_calibration is not None:  # e.g. to check a calibration against the rig
        from calibration.triangulate import StereoRig

        rig = StereoRig.load(opts.stereo_calibration)
    world = MockWorld(
        spec,
        emulator.true_positions_rad,
        cameras,
        camera_fails_after_frames=opts.camera_fails_after_frames,
    )
    arm = SerialArm(spec, emulator.port, opts.protocol)
    stack.enter_context(arm)
    perception = StereoPerception(world, rig, base_T_left, spec)
    arm.emulator = emulator  # type: ignore[attr-defined]  # tests reach the mock through the arm
    return arm, perception, world


class OpenCVStereoFrames(StereoFrameSource):
    """Two ``cv2.VideoCapture`` devices grabbed back to back, then retrieved (best alignment
    without hardware sync). A camera that delivers nothing within the timeout raises."""

    def __init__(self, indices: tuple[int, int], size: tuple[int, int], timeout_s: float) -> None:
        import cv2

        self._caps = []
        for i in indices:
            cap = cv2.VideoCapture(i)
            if not cap.isOpened():
                self.close()
                raise HardwareError(f"camera {i} could not be opened (is it plugged in and free?)")
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, size[0])
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, size[1])
            self._caps.append(cap)
        self._size = size
        self._timeout_s = timeout_s
        self._indices = indices

    def read_pair(self) -> tuple[np.ndarray, np.ndarray, float]:
        deadline = time.monotonic() + self._timeout_s
        while not all(cap.grab() for cap in self._caps):
            if time.monotonic() > deadline:
                raise HardwareError(
                    f"cameras {self._indices} stopped delivering frames for {self._timeout_s} s"
                )
        t = time.monotonic()
        frames = [cap.retrieve()[1] for cap in self._caps]
        for idx, f in zip(self._indices, frames, strict=True):
            if f is None or (f.shape[1], f.shape[0]) != self._size:
                got = None if f is None else (f.shape[1], f.shape[0])
                raise HardwareError(
                    f"camera {idx} delivers {got}, but the calibration is for {self._size}: "
                    "recalibrate or set the camera resolution"
                )
        return frames[0], frames[1], t

    def close(self) -> None:
        for cap in self._caps:
            cap.release()


class CameraWorld:
    """A real arm: nobody knows the truth, so success is judged from the camera estimates."""

    def __init__(self, threshold_m: float = 0.01) -> None:
        self.threshold_m = threshold_m

    def new_episode(self, rng: np.random.Generator) -> None:
        """The target is wherever the user put the target marker."""

    def success(self, percept: Percept) -> tuple[bool, float]:
        if percept.ee_m is None or percept.goal_m is None:
            return False, float("nan")
        d = float(np.linalg.norm(percept.ee_m - percept.goal_m))
        return d < self.threshold_m, d


def _build_serial(spec: ArmSpec, opts: DeployOptions, stack: contextlib.ExitStack) -> Built:
    from calibration.triangulate import StereoRig
    from hardware.serial_arm import SerialArm

    if opts.stereo_calibration is None or opts.base_T_left is None:
        raise ConfigError(
            "--backend serial needs --calibration (stereo) and --registration (base_T_cam)"
        )
    rig = StereoRig.load(opts.stereo_calibration)
    if rig.left.image_size != rig.right.image_size:
        raise ConfigError(
            f"stereo calibration image sizes differ: {rig.left.image_size} vs {rig.right.image_size}"
        )
    frames = OpenCVStereoFrames(opts.cameras, rig.left.image_size, opts.camera_timeout_s)
    stack.callback(frames.close)
    assert opts.port is not None
    arm = SerialArm(spec, opts.port, opts.protocol, opts.baud, opts.joint_calibration)
    stack.enter_context(arm)
    return arm, StereoPerception(frames, rig, opts.base_T_left, spec), CameraWorld()


BACKENDS: dict[str, Builder] = {"sim": _build_sim, "mock": _build_mock, "serial": _build_serial}


def deploy(
    policy_path: str | Path,
    spec: ArmSpec,
    opts: DeployOptions,
    config: LoopConfig,
    log_path: Path | None = None,
    video_path: Path | None = None,
) -> DeployResult:
    """Load the policy, check it fits this arm, build the backend, run the loop, clean up."""
    import sim2real.envs as envs
    from sim2real.export.policy import load_policy

    policy = load_policy(policy_path)
    meta = policy.meta
    meta.check_spec(spec.fingerprint())
    # The decoder must scale actions as in training (presets differ: 0.05 or 0.1 rad per step).
    env = envs.make(meta.env_id, dr="none", spec=spec, max_delta_rad=meta.max_delta_rad)
    try:
        base = env.unwrapped
        assert isinstance(base, envs.Arm3Env)
        builder, decoder = base.builder, base.decoder
        if base.task.name != "reach":
            raise ConfigError(
                f"deploy runs reach policies for now; {meta.env_id!r} is task {base.task.name!r}"
            )
    finally:
        env.close()
    meta.check_layout([(f.name, f.stop - f.start) for f in builder.layout()])
    if builder.size != meta.flat_obs_dim:
        raise ConfigError(
            f"policy expects {meta.flat_obs_dim} observations, the {meta.env_id} layout has "
            f"{builder.size}"
        )
    with contextlib.ExitStack() as stack:
        arm, perception, world = BACKENDS[opts.backend](spec, opts, stack)
        writer = None
        if video_path is not None and isinstance(perception, StereoPerception):
            import imageio.v2 as imageio

            writer = imageio.get_writer(str(video_path), fps=config.rate_hz, macro_block_size=8)
            stack.callback(writer.close)

        def on_frame() -> None:
            frames = getattr(perception, "last_frames", None)
            if writer is not None and frames is not None:
                writer.append_data(frames[0][:, :, ::-1])

        loop = DeployLoop(
            arm,
            perception,
            world,
            lambda obs: policy(obs),
            builder,
            decoder,
            config,
            log_path=log_path,
            on_frame=on_frame if writer is not None else None,
        )
        return loop.run()
