"""Wiring for ``sim2real deploy``: one registry of backends, each building (arm, perception,
world) around the same loop, for any task. Everything opened is closed by one ExitStack, in
reverse order, whatever happens."""

from __future__ import annotations

import contextlib
import dataclasses
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hardware.arm import ArmBase
from hardware.spec import ArmSpec
from sim2real.deploy.loop import DeployLoop, DeployResult, LoopConfig
from sim2real.deploy.perception import MarkerLayout, OraclePerception, Perception, StereoPerception
from sim2real.deploy.policy_io import PolicyIO, policy_io
from sim2real.deploy.realtime import control_thread_priority
from sim2real.errors import ConfigError, UnknownNameError

if TYPE_CHECKING:  # worlds import MuJoCo; the deploy profile runs without it
    from sim2real.deploy.worlds import World


@dataclass(frozen=True)
class DeployOptions:
    backend: str = "mock"
    perception: str = "cameras"  # serial: cameras | fk (forward kinematics, no cameras)
    protocol: str = "s2r"
    port: str | None = None
    baud: int | None = None
    joint_calibration: Path | None = None
    cameras: tuple[int, int] = (0, 1)
    stereo_calibration: Path | None = None
    base_T_left: np.ndarray | None = None  # noqa: N815 - frame names are part of the name
    markers: Path | None = None  # marker layout YAML (a real rig); default: the mock rig's
    dry_run: bool = False
    camera_timeout_s: float | None = None  # None: 1 s for real cameras, 5 s for the mock's
    camera_fps: float = 30.0
    camera_nice: int = 10  # mock: the render process yields to the control loop
    mock_nice: int = 5  # mock: the arm's process (emulator + physics) yields to the loop too
    mock_switch_interval_s: float | None = None  # mock: the arm process's GIL switch interval
    # mock, with realtime and the Python firmware: the arm's process at SCHED_FIFO below the loop
    mock_realtime: bool = True
    # the control loop's thread at real-time priority (SCHED_FIFO) where the OS allows it
    realtime: bool = True
    camera_fails_after_s: float | None = None  # mock fault injection: the cameras hang
    plant: str | Path | None = None  # mock: the arm as it is (a plant file or preset)
    firmware: str = "python"  # mock: the Python firmware model or the AVR binary in simavr
    # mock/sim only: a longer host and firmware watchdog (and serial reply timeout, 1/8 of it)
    # than the spec's, for simulations on a machine too loaded to hold the real ones (tests
    # under pytest -n 2). A real arm keeps the spec's.
    watchdog_s: float | None = None
    # sim: "realtime" lets physics run on with the wall clock, as a real arm does while the host
    # thinks; "lockstep" advances it one control period per command, as the env steps, whatever
    # the machine's load (bench/deploy_mock.py measures sim/env on it)
    sim_clock: str = "realtime"
    emulator_options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise UnknownNameError("backend", self.backend, BACKENDS)
        if self.backend == "serial" and not self.port:
            raise ConfigError("--backend serial needs --port (for example /dev/ttyUSB0)")
        if self.perception not in PERCEPTIONS:
            raise UnknownNameError("perception", self.perception, PERCEPTIONS)
        if self.perception != "cameras" and self.backend != "serial":
            raise ConfigError(f"--perception is for --backend serial, not {self.backend!r}")
        if self.dry_run and self.backend != "serial":
            raise ConfigError(f"--dry-run is for --backend serial, not {self.backend!r}")
        if self.plant is not None and self.backend != "mock":
            raise ConfigError(f"--plant is for --backend mock, not {self.backend!r}")
        if self.firmware != "python" and self.backend != "mock":
            raise ConfigError(f"--firmware is for --backend mock, not {self.backend!r}")
        if self.sim_clock not in SIM_CLOCKS:
            raise UnknownNameError("sim clock", self.sim_clock, SIM_CLOCKS)
        if self.watchdog_s is not None and self.backend == "serial":
            raise ConfigError("--watchdog-s is for --backend mock|sim: a real arm keeps its spec's")
        if not 0 <= self.mock_nice <= 19:
            raise ConfigError(f"mock_nice {self.mock_nice} not in [0, 19] (a niceness)")
        if not 1.0 <= self.camera_fps <= 240.0:
            raise ConfigError(f"camera_fps {self.camera_fps} not in [1, 240]")


Built = tuple[ArmBase, Perception, "World"]
Builder = Callable[[ArmSpec, PolicyIO, DeployOptions, contextlib.ExitStack], Built]


def _build_sim(
    spec: ArmSpec, io: PolicyIO, opts: DeployOptions, stack: contextlib.ExitStack
) -> Built:
    from sim2real.deploy.sim_arm import SimArm
    from sim2real.deploy.worlds import SimWorld
    from sim2real.model import RigSpec

    scene = _scene(io)
    arm = SimArm(spec, scene=scene, clock=opts.sim_clock)
    stack.enter_context(arm)
    world = SimWorld(arm, RigSpec())

    def truth() -> tuple[np.ndarray, dict[str, np.ndarray]]:
        view = world.view(arm.twin.actuator_positions(arm.data), None)
        assert view is not None
        return view.tool_m, dict(view.objects)

    return arm, OraclePerception(truth), world


def _scene(io: PolicyIO) -> str:
    from sim2real.envs import TASKS

    return TASKS[io.task].scene


def _build_mock(
    spec: ArmSpec, io: PolicyIO, opts: DeployOptions, stack: contextlib.ExitStack
) -> Built:
    """The mock arm in its own process (emulator on a pty + MuJoCo physics), the cameras
    rendering in theirs; the host holds only the serial port, the channel and perception."""
    import mujoco

    from hardware.emulator.server import EmulatorConfig
    from hardware.plant import Plant, load_plant
    from hardware.serial_arm import SerialArm
    from sim2real.deploy.mock_arm import MockArmJob, MockArmProcess
    from sim2real.deploy.render_process import RenderConfig, RenderedStereoCameras
    from sim2real.deploy.virtual_cameras import stereo_rig_of
    from sim2real.deploy.worlds import MockWorld
    from sim2real.model import RigSpec, build_mjcf

    plant = Plant.nominal(spec) if opts.plant is None else load_plant(opts.plant)
    plant.check_against(spec)
    if opts.watchdog_s is not None:  # the device's watchdog lives in the plant's firmware
        safety = dataclasses.replace(plant.spec.safety, watchdog_timeout_s=opts.watchdog_s)
        plant = dataclasses.replace(plant, spec=dataclasses.replace(plant.spec, safety=safety))
    _check_firmware(opts)
    rig, scene = RigSpec(), _scene(io)
    xml = build_mjcf(plant.spec, scene, rig, markers=True)
    model = mujoco.MjModel.from_xml_string(xml)
    cam = rig.cameras[0]
    # Rendering is a simulation's cost, not a camera's: on a loaded machine the mock's frames
    # arrive late rather than never, so its timeout is longer than a USB camera's.
    cameras = RenderedStereoCameras(
        RenderConfig(xml=xml, width_px=cam.width_px, height_px=cam.height_px,
                     fps=opts.camera_fps, nice=opts.camera_nice,
                     timeout_s=opts.camera_timeout_s or 5.0),
        model.nq, model.nmocap,
    )  # fmt: skip
    stack.callback(cameras.close)
    cameras.start()
    job = MockArmJob(
        plant=plant, scene=scene, protocol=opts.protocol, firmware=opts.firmware,
        emulator_config=EmulatorConfig(**opts.emulator_options), rig=rig,
        state_block=cameras.state_block, nice=opts.mock_nice,
        switch_interval_s=opts.mock_switch_interval_s,
        realtime_priority=_mock_priority(opts),
    )  # fmt: skip
    arm_process = stack.enter_context(MockArmProcess(job))
    world = MockWorld(arm_process, cameras)
    stereo, base_T_left = stereo_rig_of(rig)
    if opts.stereo_calibration is not None:  # the user's calibration of the rendered rig
        from calibration.triangulate import StereoRig

        stereo = StereoRig.load(opts.stereo_calibration)
    if opts.base_T_left is not None:
        base_T_left = opts.base_T_left
    relaxed: dict[str, Any] = {}
    if opts.watchdog_s is not None:  # a loaded machine: the arm's process may answer late too
        relaxed = {"host_watchdog_s": opts.watchdog_s, "timeout_s": max(0.05, opts.watchdog_s / 8)}
    # a host-side joint calibration (adapt's fitted zero offsets) acts on the mock as on a bus
    arm = SerialArm(
        spec, arm_process.port, opts.protocol, calibration=opts.joint_calibration, **relaxed
    )
    stack.enter_context(arm)
    arm.emulator = arm_process  # type: ignore[attr-defined]  # tests reach the mock through the arm
    arm.world = world  # type: ignore[attr-defined]
    perception = _stereo_perception(cameras, stereo, base_T_left, spec, io, opts, stack)
    if opts.camera_fails_after_s is not None:  # fault injection: after the first frames
        import threading

        timer = threading.Timer(opts.camera_fails_after_s, cameras.freeze)
        timer.daemon = True
        timer.start()
        stack.callback(timer.cancel)
    return arm, perception, world


def _mock_priority(opts: DeployOptions) -> int | None:
    """The mock arm's real-time priority, below the loop's; never for a firmware binary (its
    simulator is a busy process, which would hold a core at real-time priority)."""
    from sim2real.deploy.realtime import CONTROL_PRIORITY, niced

    if opts.realtime and opts.mock_realtime and opts.firmware == "python" and not niced():
        return CONTROL_PRIORITY - 10
    return None


def _check_firmware(opts: DeployOptions) -> None:
    """Refused in the host, before the arm's process starts."""
    if opts.firmware == "python":
        return
    from hardware.emulator import FIRMWARES

    if opts.firmware not in FIRMWARES:
        raise UnknownNameError("firmware", opts.firmware, FIRMWARES)
    if opts.protocol != "s2r":
        raise ConfigError(f"--firmware {opts.firmware} speaks s2r, not {opts.protocol!r}")


def _stereo_perception(
    frames: Any,
    stereo: Any,
    base_T_left: np.ndarray,
    spec: ArmSpec,
    io: PolicyIO,
    opts: DeployOptions,
    stack: contextlib.ExitStack,
) -> StereoPerception:
    from sim2real.deploy.frames import wait_first

    layout = MarkerLayout.for_spec(spec)
    if opts.markers is not None:
        layout = MarkerLayout.load(opts.markers, spec)
    perception = StereoPerception(frames, stereo, base_T_left, spec, io.contract.objects, layout)
    # start-up, before torque is on: a render process imports MuJoCo
    perception.check_frames(wait_first(frames, 60.0))
    perception.start()
    stack.callback(perception.close)
    return perception


def _build_serial(
    spec: ArmSpec, io: PolicyIO, opts: DeployOptions, stack: contextlib.ExitStack
) -> Built:
    if opts.perception == "fk":  # no cameras (and no MuJoCo): sim2real.deploy.kinematic
        from sim2real.deploy.kinematic import build_serial_fk

        return build_serial_fk(spec, io, opts, stack)
    from calibration.triangulate import StereoRig
    from hardware.serial_arm import SerialArm
    from sim2real.deploy.frames import OpenCVStereoCameras
    from sim2real.deploy.worlds import CameraWorld

    if opts.stereo_calibration is None or opts.base_T_left is None:
        raise ConfigError(
            "--backend serial needs --calibration (stereo) and --registration (base_T_cam)"
        )
    stereo = StereoRig.load(opts.stereo_calibration)
    if stereo.left.image_size != stereo.right.image_size:
        raise ConfigError(
            f"stereo calibration image sizes differ: {stereo.left.image_size} vs "
            f"{stereo.right.image_size}"
        )
    frames = OpenCVStereoCameras(opts.cameras, stereo.left.image_size, opts.camera_timeout_s or 1.0)
    stack.callback(frames.close)
    frames.start()
    assert opts.port is not None
    arm = SerialArm(spec, opts.port, opts.protocol, opts.baud, opts.joint_calibration)
    stack.enter_context(arm)
    perception = _stereo_perception(frames, stereo, opts.base_T_left, spec, io, opts, stack)
    return arm, perception, CameraWorld()


PERCEPTIONS: tuple[str, ...] = ("cameras", "fk")
SIM_CLOCKS: tuple[str, ...] = ("lockstep", "realtime")  # sim_arm.CLOCKS, without MuJoCo
BACKENDS: dict[str, Builder] = {"sim": _build_sim, "mock": _build_mock, "serial": _build_serial}


def deploy(
    policy_ref: str | Path,
    spec: ArmSpec,
    opts: DeployOptions,
    config: LoopConfig,
    log_path: Path | None = None,
    video_path: Path | None = None,
    dataset_path: Path | None = None,
) -> DeployResult:
    """Load the policy (a run dir, an exported file or a shipped name), check it fits this arm,
    build the backend around the task's contract, run the loop, clean up."""
    from sim2real.export.policy import load_policy
    from sim2real.policies import resolve_policy

    policy = load_policy(resolve_policy(policy_ref))
    meta = policy.meta
    meta.check_spec(spec.fingerprint())
    io = policy_io(spec, meta)
    if abs(meta.control_hz - config.rate_hz) > 1e-9:
        raise ConfigError(
            f"policy {meta.source!r} was trained at {meta.control_hz:g} Hz; deploy it at that "
            f"rate (--rate {meta.control_hz:g}), not {config.rate_hz:g} Hz"
        )
    return run_policy(
        lambda obs: policy(obs), io, spec, opts, config, log_path, video_path, meta.obs_keys,
        dataset_path,
    )  # fmt: skip


def run_policy(
    policy: Callable[[Any], np.ndarray],
    io: PolicyIO,
    spec: ArmSpec,
    opts: DeployOptions,
    config: LoopConfig,
    log_path: Path | None = None,
    video_path: Path | None = None,
    obs_keys: tuple[str, ...] | None = None,
    dataset_path: Path | None = None,
) -> DeployResult:
    """Any callable policy on a backend (a scripted one in tests, a learner's actor)."""
    with contextlib.ExitStack() as stack:
        arm, perception, world = BACKENDS[opts.backend](spec, io, opts, stack)
        cameras = isinstance(perception, StereoPerception)
        writer = None
        if video_path is not None and cameras:
            import imageio.v2 as imageio

            writer = imageio.get_writer(str(video_path), fps=config.rate_hz, macro_block_size=8)
            stack.callback(writer.close)
        recorder = None
        if dataset_path is not None:
            from sim2real.deploy.recording import DeployRecorder

            recorder = DeployRecorder(dataset_path, spec, io, config.rate_hz, cameras)

        def on_frame() -> None:
            frames = perception.last_frames if isinstance(perception, StereoPerception) else None
            if writer is not None and frames is not None:
                writer.append_data(frames[0][:, :, ::-1])
            if recorder is not None:
                recorder.on_period(frames)

        loop = DeployLoop(
            arm,
            perception,
            world,
            policy,
            io,
            config,
            log_path=log_path,
            on_frame=on_frame if writer is not None or recorder is not None else None,
            obs_keys=obs_keys,
            on_episode=None if recorder is None else recorder.on_episode,
        )
        # the serial link's reader wakes the loop when a reply arrives: it is on the loop's path
        reader = getattr(getattr(arm, "link", None), "_thread", None)
        helpers = [reader] if isinstance(reader, threading.Thread) else []
        try:
            with control_thread_priority(opts.realtime, helpers=helpers):
                result = loop.run()
        except BaseException:
            if recorder is not None:  # nothing half-written: the episodes so far are dropped
                recorder.abort()
            raise
        if recorder is not None:
            recorder.close()  # the episodes recorded, even after a Ctrl-C
        result.arm = arm  # type: ignore[attr-defined]  # tests inspect the mock through it
        return result
