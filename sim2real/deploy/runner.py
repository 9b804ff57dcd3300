"""Wiring for ``sim2real deploy``: the builders of the backends ``connection.BACKENDS``
registers, each opening (arm, perception, world) around the same loop, for any task. Everything
opened is closed by one ExitStack, in reverse order, whatever happens."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from hardware.arm import ArmBase
from hardware.feedback import readings_mismatch, spec_protocol_problem
from hardware.spec import ArmSpec
from sim2real.deploy.connection import BACKENDS, PERCEPTIONS, SIM_CLOCKS, ArmConnection
from sim2real.deploy.loop import DeployLoop, DeployResult, LoopConfig
from sim2real.deploy.perception import MarkerLayout, OraclePerception, Perception, StereoPerception
from sim2real.deploy.policy_io import PolicyIO, policy_io
from sim2real.deploy.realtime import control_thread_priority
from sim2real.errors import ConfigError

if TYPE_CHECKING:  # worlds import MuJoCo; the deploy profile runs without it
    from sim2real.deploy.worlds import World


# A deploy's options are the arm connection (``connection.ArmConnection``): the name is kept
# for the code and scripts that build one by it.
DeployOptions = ArmConnection


class LivePeriods(Protocol):
    """Where a live view takes each period (``sim2real.view.live.LiveProcess``; the deploy
    runtime does not import the viewer): it must return at once, whatever its consumer does."""

    def log_period(self, row: Mapping[str, Any], frames_bgr: Any = None) -> bool: ...


__all__ = ["BACKENDS", "PERCEPTIONS", "SIM_CLOCKS", "DeployOptions", "deploy", "run_policy"]

Built = tuple[ArmBase, Perception, "World"]


def build_sim(
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


def check_protocol_readings(spec: ArmSpec, protocol: str) -> None:
    """Before a port is opened: the spec's reading kinds must be ones ``protocol`` can deliver
    (``hardware.feedback.READING_SOURCES``), one line naming the joints otherwise."""
    why = spec_protocol_problem(spec, protocol)
    if why:
        raise ConfigError(
            f"{why}: declare each joint's feedback as its servos report it (feedback: commanded "
            "for bare PWM servos)"
        )


def check_device_readings(arm: ArmBase, spec: ArmSpec) -> None:
    """At connect: the device's reading kinds (its first state's ``measured``) must be the
    spec's, or the policy, trained on the spec's kinds, would run on the other kind."""
    why = readings_mismatch(spec, arm.read_state().measured_mask)
    if why:
        raise ConfigError(
            f"{why}: use the spec of the build on the port (potentiometers wired: measured; "
            "bare PWM servos: commanded), or flash the board with this spec's limits"
        )


def _scene(io: PolicyIO) -> str:
    from sim2real.envs import TASKS

    return TASKS[io.task].scene


def build_mock(
    spec: ArmSpec, io: PolicyIO, opts: DeployOptions, stack: contextlib.ExitStack
) -> Built:
    """The mock arm in its own process (emulator on a pty + MuJoCo physics), the cameras
    rendering in theirs; the host holds only the serial port, the channel and perception."""
    from hardware.emulator.server import EmulatorConfig
    from hardware.serial_arm import SerialArm
    from sim2real.deploy.mock_arm import MockArmJob, MockArmProcess
    from sim2real.deploy.worlds import MockWorld
    from sim2real.model import RigSpec

    check_protocol_readings(spec, opts.protocol)
    plant = opts.plant_for(spec)  # checked against the spec, its watchdog relaxed if asked
    rig, scene = RigSpec(), _scene(io)
    stereo, base_T_left = _mock_stereo(rig, opts)  # its files read before anything starts
    cameras = _mock_cameras(plant.spec, scene, rig, opts, stack)
    job = MockArmJob(
        plant=plant, scene=scene, protocol=opts.protocol, firmware=opts.firmware,
        emulator_config=EmulatorConfig(**opts.emulator_options), rig=rig,
        state_block=cameras.state_block, nice=opts.mock_nice,
        switch_interval_s=opts.mock_switch_interval_s,
        realtime_priority=_mock_priority(opts),
    )  # fmt: skip
    arm_process = stack.enter_context(MockArmProcess(job))
    world = MockWorld(arm_process, cameras)
    # a host-side joint calibration (adapt's fitted zero offsets) acts on the mock as on a bus;
    # on a loaded machine (watchdog_s) the arm's process may answer late too
    arm = SerialArm(
        spec,
        arm_process.port,
        opts.protocol,
        calibration=opts.joint_calibration,
        **opts.relaxed_host(),
    )
    stack.enter_context(arm)
    check_device_readings(arm, spec)
    arm.emulator = arm_process  # type: ignore[attr-defined]  # tests reach the mock through the arm
    arm.world = world  # type: ignore[attr-defined]
    perception = _stereo_perception(cameras, stereo, base_T_left, spec, io, opts, stack)
    if opts.camera_fails_after_s is not None:  # fault injection: after the first frames
        timer = threading.Timer(opts.camera_fails_after_s, cameras.freeze)
        timer.daemon = True
        timer.start()
        stack.callback(timer.cancel)
    return arm, perception, world


def _mock_cameras(
    plant_spec: ArmSpec, scene: str, rig: Any, opts: DeployOptions, stack: contextlib.ExitStack
) -> Any:
    """The rig's two cameras rendering the plant's scene in a process of their own, started.
    Rendering is a simulation's cost, not a camera's: on a loaded machine the mock's frames
    arrive late rather than never, so its timeout is longer than a USB camera's."""
    from sim2real.deploy.render_process import RenderConfig, RenderedStereoCameras
    from sim2real.twin_mjcf import TwinScene

    twin = TwinScene(plant_spec, scene, rig, markers=True)
    model = twin.model()
    cam = rig.cameras[0]
    cameras = RenderedStereoCameras(
        RenderConfig(twin=twin, width_px=cam.width_px, height_px=cam.height_px,
                     fps=opts.camera_fps, nice=opts.camera_nice,
                     timeout_s=opts.camera_timeout_s or 5.0),
        model.nq, model.nmocap,
    )  # fmt: skip
    stack.callback(cameras.close)
    cameras.start()
    return cameras


def _mock_stereo(rig: Any, opts: DeployOptions) -> tuple[Any, np.ndarray]:
    """The rendered rig's stereo model and registration, or the user's calibration of it."""
    from sim2real.deploy.virtual_cameras import stereo_rig_of

    stereo, base_T_left = stereo_rig_of(rig)
    if opts.stereo_calibration is not None:
        from calibration.triangulate import StereoRig

        stereo = StereoRig.load(opts.stereo_calibration)
    registered = opts.load_registration()
    return stereo, base_T_left if registered is None else registered


def _mock_priority(opts: DeployOptions) -> int | None:
    """The mock arm's real-time priority, below the loop's; never for a firmware binary (its
    simulator is a busy process, which would hold a core at real-time priority)."""
    from sim2real.deploy.realtime import CONTROL_PRIORITY, niced

    if opts.realtime and opts.mock_realtime and opts.firmware == "python" and not niced():
        return CONTROL_PRIORITY - 10
    return None


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


def build_serial(
    spec: ArmSpec, io: PolicyIO, opts: DeployOptions, stack: contextlib.ExitStack
) -> Built:
    check_protocol_readings(spec, opts.protocol)
    if opts.perception == "fk":  # no cameras (and no MuJoCo): sim2real.deploy.kinematic
        from sim2real.deploy.kinematic import build_serial_fk

        return build_serial_fk(spec, io, opts, stack)
    from calibration.triangulate import StereoRig
    from hardware.serial_arm import SerialArm
    from sim2real.deploy.frames import OpenCVStereoCameras
    from sim2real.deploy.worlds import CameraWorld

    opts.require_cameras()
    assert opts.stereo_calibration is not None and opts.port is not None
    base_T_left = opts.load_registration()
    assert base_T_left is not None
    stereo = StereoRig.load(opts.stereo_calibration)
    if stereo.left.image_size != stereo.right.image_size:
        raise ConfigError(
            f"stereo calibration image sizes differ: {stereo.left.image_size} vs "
            f"{stereo.right.image_size}"
        )
    frames = OpenCVStereoCameras(opts.cameras, stereo.left.image_size, opts.camera_timeout_s or 1.0)
    stack.callback(frames.close)
    frames.start()
    arm = SerialArm(spec, opts.port, opts.protocol, opts.baud, opts.joint_calibration)
    stack.enter_context(arm)
    check_device_readings(arm, spec)
    perception = _stereo_perception(frames, stereo, base_T_left, spec, io, opts, stack)
    return arm, perception, CameraWorld()


def deploy(
    policy_ref: str | Path,
    spec: ArmSpec,
    opts: DeployOptions,
    config: LoopConfig,
    log_path: Path | None = None,
    video_path: Path | None = None,
    dataset_path: Path | None = None,
    live: LivePeriods | None = None,
) -> DeployResult:
    """Load the policy (a run dir, an exported file or a shipped name), check it fits this arm,
    build the backend around the task's contract, run the loop, clean up."""
    from sim2real.export.policy import load_policy
    from sim2real.policies import resolve_policy

    policy = load_policy(resolve_policy(policy_ref))
    meta = policy.meta
    meta.check_spec(spec)
    io = policy_io(spec, meta)
    if abs(meta.control_hz - config.rate_hz) > 1e-9:
        raise ConfigError(
            f"policy {meta.source!r} was trained at {meta.control_hz:g} Hz; deploy it at that "
            f"rate (--rate {meta.control_hz:g}), not {config.rate_hz:g} Hz"
        )
    return run_policy(
        lambda obs: policy(obs), io, spec, opts, config, log_path, video_path, meta.obs_keys,
        dataset_path, live,
    )  # fmt: skip


def _outputs(
    stack: contextlib.ExitStack,
    perception: Any,
    spec: ArmSpec,
    io: PolicyIO,
    config: LoopConfig,
    video_path: Path | None,
    dataset_path: Path | None,
) -> tuple[Any, Any]:
    """What a run writes besides its log: a video of the left camera, a LeRobot dataset."""
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
    return writer, recorder


def _on_frame(
    perception: Any,
    writer: Any,
    recorder: Any,
    live: LivePeriods | None,
    rows: Callable[[], Mapping[str, list[Any]]],
) -> Callable[[], None] | None:
    """The loop's per-period callback feeding them (None: nothing to feed)."""
    if writer is None and recorder is None and live is None:
        return None

    def on_frame() -> None:
        frames = perception.last_frames if isinstance(perception, StereoPerception) else None
        if writer is not None and frames is not None:
            writer.append_data(frames[0][:, :, ::-1])
        if recorder is not None:
            recorder.on_period(frames)
        if live is not None:
            live.log_period({k: v[-1] for k, v in rows().items() if v}, frames)

    return on_frame


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
    live: LivePeriods | None = None,
) -> DeployResult:
    """Any callable policy on a backend (a scripted one in tests, a learner's actor). ``live``
    (``sim2real.view.live.LiveProcess``) gets each period's log row and camera pair from the
    control thread; it only posts them (its child process draws off the loop's path)."""
    with contextlib.ExitStack() as stack:
        arm, perception, world = BACKENDS[opts.backend](spec, io, opts, stack)
        bind = getattr(policy, "bind", None)
        if callable(bind):  # a privileged teacher (privileged.TruthTeacher) reads the truth
            world = bind(arm, world)
        writer, recorder = _outputs(stack, perception, spec, io, config, video_path, dataset_path)
        on_frame = _on_frame(perception, writer, recorder, live, lambda: loop.log.rows)
        loop = DeployLoop(
            arm,
            perception,
            world,
            policy,
            io,
            config,
            log_path=log_path,
            on_frame=on_frame,
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
            if recorder is not None:  # the queue drained, the finished episodes kept whole
                recorder.finish_after_fault()
            raise
        if recorder is not None:
            recorder.close()  # the episodes recorded, even after a Ctrl-C
        result.arm = arm  # type: ignore[attr-defined]  # tests inspect the mock through it
        return result
