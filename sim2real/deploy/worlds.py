"""Worlds: what is out there besides the arm, who places it, and who knows the truth.

* ``SimWorld``: the ``SimArm``'s own MuJoCo scene; truth from its state.
* ``MockPhysics``: the mock arm's physics, in the mock arm's own process beside the emulator.
  The emulator decides where each servo drives (its setpoint after the firmware, faults,
  latency and rate limit); MuJoCo's torque-limited actuators move the arm and the fingers
  there, with gravity, contacts, grasps and a falling cube, and the emulated servos read the
  horns back from MuJoCo, as a real servo's potentiometer would (a cube between the fingers
  stalls the gripper where it touches). The scene state is published to free-running virtual
  cameras (``render_process``), which render it outside the control loop.
* ``MockWorld``: the host's side of it (place, clear and the truth over the process boundary).
* ``CameraWorld``: a real arm. Nobody knows the truth; a person places the objects.

Placement and truth go through ``SceneObjects``, one name → MuJoCo mapping for every task.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

import mujoco
import numpy as np

from hardware.emulator.coupling import BodyCoupling
from hardware.spec import ArmSpec
from sim2real import model as names
from sim2real.camera_rig import RigSpec
from sim2real.envs.contract import View
from sim2real.twin import ArmTwin
from sim2real.twin_mjcf import build_model

if TYPE_CHECKING:
    from sim2real.deploy.mock_arm import MockArmProcess
    from sim2real.deploy.render_process import RenderedStereoCameras

log = logging.getLogger(__name__)


class World(Protocol):
    places_objects: bool  # sim and mock place the objects; on a real arm a person does

    def new_episode(self, placement: dict[str, np.ndarray]) -> None:
        """Put the task's objects where the contract says (a real arm: a person does)."""
        ...

    def clear(self) -> None:
        """Between episodes: objects out of the arm's way (a real arm: nothing to do)."""
        ...

    def view(self, actuators_rad: np.ndarray, commanded_rad: np.ndarray | None) -> View | None:
        """The truth for judging success, or None where there is none (a real arm)."""
        ...

    def close(self) -> None: ...


def _yaw_quat(yaw_rad: float) -> np.ndarray:
    return np.array([np.cos(yaw_rad / 2), 0.0, 0.0, np.sin(yaw_rad / 2)])


class SceneObjects:
    """The task objects of one compiled scene, ids resolved once: placing and reading them."""

    def __init__(self, model: mujoco.MjModel, rig: RigSpec) -> None:
        self.model, self.rig = model, rig
        self.target_mocap = int(model.body_mocapid[model.body(names.TARGET_BODY).id])
        self.cube_qadr = self.cube_dofadr = -1
        self.cube_body = -1
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, names.CUBE_JOINT) >= 0:
            j = model.joint(names.CUBE_JOINT)
            self.cube_qadr, self.cube_dofadr = int(j.qposadr[0]), int(j.dofadr[0])
            self.cube_body = model.body(names.CUBE_BODY).id
            self.cube_geom = model.geom(names.CUBE_GEOM).id
            self.finger_geoms = frozenset(model.geom(g).id for g in names.FINGER_GEOMS)
        self.seam_mocap = -1
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, names.SEAM_BODY) >= 0:
            self.seam_mocap = int(model.body_mocapid[model.body(names.SEAM_BODY).id])
        self._seam = (np.zeros(3), 0.0)

    def place(self, data: mujoco.MjData, placement: dict[str, np.ndarray]) -> None:
        """Apply a contract's placement (the caller runs mj_forward)."""
        from sim2real.deploy.virtual_cameras import target_quat_facing

        for key, pose in placement.items():
            pose = np.asarray(pose, dtype=float)
            if key == "target":
                data.mocap_pos[self.target_mocap] = pose[:3]
                data.mocap_quat[self.target_mocap] = target_quat_facing(self.rig, pose[:3])
            elif key == "cube" and self.cube_qadr >= 0:
                half = float(self.model.geom_size[self.cube_geom][2])
                a, v = self.cube_qadr, self.cube_dofadr
                data.qpos[a : a + 3] = (pose[0], pose[1], half)
                data.qpos[a + 3 : a + 7] = _yaw_quat(float(pose[2]))
                data.qvel[v : v + 6] = 0.0
            elif key == "seam" and self.seam_mocap >= 0:
                data.mocap_pos[self.seam_mocap] = (pose[0], pose[1], names.SEAM_BODY_Z_M)
                data.mocap_quat[self.seam_mocap] = _yaw_quat(float(pose[2]))
                self._seam = (np.array([pose[0], pose[1], 0.0]), float(pose[2]))
            else:
                raise KeyError(f"this scene has no {key!r} to place")
        if "target" not in placement:  # park the unused target plate out of view
            data.mocap_pos[self.target_mocap] = (0.0, 0.0, -1.0)

    def clear(self, data: mujoco.MjData) -> None:
        """Take the objects off the table (between episodes the arm homes with nothing in its
        way or in its fingers; the next placement puts them back)."""
        data.mocap_pos[self.target_mocap] = (0.0, 0.0, -1.0)
        if self.cube_qadr >= 0:
            a, v = self.cube_qadr, self.cube_dofadr
            data.qpos[a : a + 3] = (-0.4, 0.4, 0.05)
            data.qpos[a + 3 : a + 7] = (1.0, 0.0, 0.0, 0.0)
            data.qvel[v : v + 6] = 0.0

    def truth(self, data: mujoco.MjData) -> dict[str, np.ndarray]:
        out = {"target": data.mocap_pos[self.target_mocap].copy()}
        if self.cube_body >= 0:
            out["cube"] = data.xpos[self.cube_body].copy()
        if self.seam_mocap >= 0:
            start, heading = self._seam
            d = np.array([np.cos(heading), np.sin(heading), 0.0])
            out["seam_start"] = start
            out["seam_end"] = start + names.SEAM_LENGTH_M * d
        return out

    def fingers_on_cube(self, data: mujoco.MjData) -> int:
        """How many fingers touch the cube (MuJoCo's contact list)."""
        if self.cube_body < 0:
            return 0
        touching: set[int] = set()
        for i in range(data.ncon):
            c = data.contact[i]
            g1, g2 = int(c.geom1), int(c.geom2)
            if g1 == self.cube_geom and g2 in self.finger_geoms:
                touching.add(g2)
            elif g2 == self.cube_geom and g1 in self.finger_geoms:
                touching.add(g1)
        return len(touching)


class SimWorld:
    """Truth from the ``SimArm``'s MuJoCo state; objects placed in its scene."""

    places_objects = True

    def __init__(self, arm: object, rig: RigSpec) -> None:
        from sim2real.deploy.sim_arm import SimArm

        assert isinstance(arm, SimArm)
        self.arm = arm
        self.objects = SceneObjects(arm.model, rig)

    def new_episode(self, placement: dict[str, np.ndarray]) -> None:
        self.objects.place(self.arm.data, placement)
        mujoco.mj_forward(self.arm.model, self.arm.data)

    def clear(self) -> None:
        """Objects off the table, and the fingers reset to where their servo drives them: a
        simulated cube squeezed out of the fingers can leave them jammed."""
        self.objects.clear(self.arm.data)
        self.arm.twin.unjam_fingers(self.arm.data)
        mujoco.mj_forward(self.arm.model, self.arm.data)

    def view(self, actuators_rad: np.ndarray, commanded_rad: np.ndarray | None) -> View | None:
        """The loop's thread is the SimArm's only user: no lock needed."""
        tool = self.arm.tool_position()  # catches physics up with the wall clock first
        d = self.arm.data
        cube = self.objects.cube_body >= 0
        return View(
            tool_m=tool,
            objects=self.objects.truth(d),
            actuators_rad=actuators_rad,
            truth=True,
            grasped=self.objects.fingers_on_cube(d) == 2 if cube else None,
            commanded_rad=commanded_rad,
        )

    def close(self) -> None:
        """The arm owns the scene."""


Truth = tuple[np.ndarray, dict[str, np.ndarray], bool | None]  # tool, objects, grasped
StateSink = Callable[[float, mujoco.MjData, Truth], None]


def _geoms_below(model: mujoco.MjModel, root: int) -> np.ndarray:
    """A mask over the model's geoms: those on body ``root`` or any body below it."""
    below = np.zeros(model.nbody, dtype=bool)
    for b in range(model.nbody):  # parents come before children in MuJoCo's body order
        below[b] = b == root or (b > 0 and below[model.body_parentid[b]])
    return below[model.geom_bodyid]


class MockPhysics:
    """The mock arm's world: emulator-driven MuJoCo physics in a real-time thread. It runs in
    the mock arm's own process (``mock_arm``), beside the emulator, never in the host's: after
    each step it hands the scene state and the truth to ``sink`` (shared memory for the
    free-running cameras and for ``MockWorld.view``).

    The emulator's servos drive the arm as a real servo drives its horn: each servo's setpoint
    (after the device's firmware, faults, command latency and rate limit) is the target of the
    twin's torque-limited position actuator, the same actuator the envs train with, built from
    the plant's servo figures. MuJoCo decides where the horns go, lagging, sagging under gravity
    and stalling on the cube, and the emulator reads them back from there (``sense``)."""

    STEP_CATCH_UP_MAX = 20  # physics steps per wake-up at most (a stalled thread jumps ahead)

    def __init__(
        self,
        spec: ArmSpec,
        scene: str,
        emulator: BodyCoupling,
        rig: RigSpec | None = None,
        sink: StateSink | None = None,
        on_error: Callable[[BaseException], None] | None = None,
    ) -> None:
        """``spec`` is the arm as it really is (a plant's), not the policy's belief."""
        self.spec = spec
        self.rig = rig or RigSpec()
        self.emulator = emulator
        self.model = build_model(spec, scene, self.rig, markers=True)
        self.data = mujoco.MjData(self.model)
        self.twin = ArmTwin(self.model, spec)
        self.objects = SceneObjects(self.model, self.rig)
        self.lock = threading.Lock()
        self.sink = sink
        self.on_error = on_error
        # physics steps with a moving link (upper arm and below) touching the table: what the
        # workspace guard exists to keep at 0, measured by MuJoCo's own contacts
        self.table_contacts = 0
        table = self.model.geom(names.TABLE_GEOM).id
        link = _geoms_below(self.model, self.model.body(names.LINK_ROOT_BODY).id)
        # [geom1, geom2] -> a link on the table: one lookup per contact in the physics loop
        self._table_link = np.zeros((self.model.ngeom, self.model.ngeom), dtype=bool)
        self._table_link[table, link] = self._table_link[link, table] = True
        self._n = spec.n_joints
        self._running = False
        self._thread: threading.Thread | None = None
        self._published_t = -np.inf
        self._requests: queue.SimpleQueue[_Request] = queue.SimpleQueue()
        self.steps = 0
        self.error: BaseException | None = None
        emulator.attach_body()
        q = emulator.true_positions_rad()
        self.twin.set_pose(self.data, q, self._gripper(q))
        self._drive(q)
        mujoco.mj_forward(self.model, self.data)
        self._sense()

    # ---- lifecycle --------------------------------------------------------------------------
    def start(self) -> None:
        self._publish(time.monotonic())
        self._running = True
        self._thread = threading.Thread(target=self._run, name="mock-physics", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    # ---- physics ----------------------------------------------------------------------------
    def _gripper(self, q_rad: np.ndarray) -> float | None:
        return float(q_rad[self._n]) if self.twin.has_gripper else None

    def _drive(self, setpoint_rad: np.ndarray) -> None:
        """The servos' setpoints become the actuators' targets."""
        self.twin.write_ctrl(self.data, setpoint_rad[: self._n], self._gripper(setpoint_rad))

    def _sense(self) -> None:
        """The horns are where MuJoCo put them: the emulated servos read that."""
        d = self.data
        self.emulator.sense(self.twin.actuator_positions(d), self.twin.actuator_velocities(d))

    def _run(self) -> None:
        dt = float(self.model.opt.timestep)
        t0 = time.monotonic()
        done = 0
        prev = self.emulator.setpoints_rad()
        try:
            while self._running:
                now = time.monotonic()
                behind = int((now - t0) / dt) - done
                if behind > self.STEP_CATCH_UP_MAX:  # stalled (a loaded machine): jump ahead
                    done += behind - self.STEP_CATCH_UP_MAX
                    behind = self.STEP_CATCH_UP_MAX
                if behind > 0:
                    setpoint = self.emulator.setpoints_rad()
                    step = (setpoint - prev) / behind
                    with self.lock:
                        for k in range(1, behind + 1):  # the setpoint's motion over the steps
                            self._drive(prev + step * k)
                            mujoco.mj_step(self.model, self.data)
                            self.table_contacts += self._touches_table()
                        self.steps += behind
                    self._sense()
                    prev = setpoint
                    done += behind
                    self._publish(now)
                self._serve_requests()
                time.sleep(max(0.0, t0 + (done + 1) * dt - time.monotonic()))
        except BaseException as exc:  # a dead world must stop the arm's process
            self.error = exc
            self._serve_requests(exc)
            log.error("mock physics stopped: %s", exc)
            if self.on_error is not None:
                self.on_error(exc)

    def _touches_table(self) -> int:
        """1 if any contact pairs the table with a moving link, else 0."""
        if self.data.ncon == 0:
            return 0
        pairs = self.data.contact.geom  # (ncon, 2)
        return int(self._table_link[pairs[:, 0], pairs[:, 1]].any())

    def truth(self) -> Truth:
        """Tool, objects and grasp from the current state (caller holds the lock)."""
        d = self.data
        grasped = self.objects.fingers_on_cube(d) == 2 if self.objects.cube_body >= 0 else None
        return self.twin.tool_position(d).copy(), self.objects.truth(d), grasped

    def _publish(self, t_s: float) -> None:
        """One writer at a time, times never going backwards (the physics thread and the
        control channel both publish; the trackers refuse time running backwards)."""
        with self.lock:
            self._published_t = max(t_s, self._published_t)
            if self.sink is not None:
                self.sink(self._published_t, self.data, self.truth())

    # ---- what the control channel asks --------------------------------------------------------
    def _serve_requests(self, failed: BaseException | None = None) -> None:
        while True:
            try:
                request = self._requests.get_nowait()
            except queue.Empty:
                return
            with self.lock:
                request.run(failed)

    def _in_physics(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` in the physics thread between two batches of steps. (Taking the lock from
        another thread starves: a physics thread that is behind takes it back at once, and a
        placement waited hundreds of milliseconds on a loaded machine.)"""
        thread = self._thread
        if thread is None or not thread.is_alive() or thread is threading.current_thread():
            with self.lock:
                fn()
            return
        request = _Request(fn)
        self._requests.put(request)
        while not request.done.wait(0.5):
            if not thread.is_alive():
                raise RuntimeError(f"mock physics stopped: {self.error}")
        request.raise_error()

    def _place(self, placement: dict[str, np.ndarray]) -> None:
        self.objects.place(self.data, placement)
        mujoco.mj_forward(self.model, self.data)

    def _clear(self) -> None:
        """Objects off the table; fingers that a cube squeezed out of their slides go back to
        where their servo drives them."""
        self.objects.clear(self.data)
        self.twin.unjam_fingers(self.data)
        mujoco.mj_forward(self.model, self.data)

    def new_episode(self, placement: dict[str, np.ndarray]) -> None:
        self._in_physics(lambda: self._place(placement))
        self._publish(time.monotonic())

    def clear(self) -> None:
        self._in_physics(self._clear)
        self._publish(time.monotonic())


class _Request:
    """One call the physics thread runs for another thread, which waits for it."""

    def __init__(self, fn: Callable[[], None]) -> None:
        self.fn, self.done = fn, threading.Event()
        self.error: BaseException | None = None

    def run(self, failed: BaseException | None) -> None:
        try:
            if failed is not None:
                raise RuntimeError(f"mock physics stopped: {failed}") from failed
            self.fn()
        except BaseException as exc:
            self.error = exc
        finally:
            self.done.set()

    def raise_error(self) -> None:
        if self.error is not None:
            raise self.error


class MockWorld:
    """The host's side of the mock arm's world. The physics runs in the mock arm's own process
    (``mock_arm.MockArmProcess``), as a real arm's world is outside the host: placing and
    clearing go over its control channel, the truth is read from shared memory without
    waiting, and the cameras render in their own process."""

    places_objects = True

    def __init__(self, arm_process: MockArmProcess, cameras: RenderedStereoCameras) -> None:
        self.process, self.cameras = arm_process, cameras

    def new_episode(self, placement: dict[str, np.ndarray]) -> None:
        self.process.call("place", {k: np.asarray(v, dtype=float) for k, v in placement.items()})

    def clear(self) -> None:
        self.process.call("clear")

    def view(self, actuators_rad: np.ndarray, commanded_rad: np.ndarray | None) -> View | None:
        tool, objects, grasped = self.process.truth()
        return View(
            tool_m=tool,
            objects=objects,
            actuators_rad=actuators_rad,
            truth=True,
            grasped=grasped,
            commanded_rad=commanded_rad,
        )

    def table_contacts(self) -> int | None:
        """Physics steps with an arm link on the table so far (``MockPhysics``)."""
        return self.process.table_contacts()

    def close(self) -> None:
        """The backend's exit stack stops the arm's process and the cameras."""


class CameraWorld:
    """A real arm: a person places the objects; success is judged from the camera estimates."""

    places_objects = False

    def new_episode(self, placement: dict[str, np.ndarray]) -> None:
        """Nothing to do: the loop waits until the contract's objects are seen and still."""

    def clear(self) -> None:
        """A person takes the cube (home opens the gripper)."""

    def view(self, actuators_rad: np.ndarray, commanded_rad: np.ndarray | None) -> View | None:
        return None

    def close(self) -> None:
        """Nothing to release."""
