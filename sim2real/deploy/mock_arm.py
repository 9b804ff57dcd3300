"""The mock arm in its own process, as a real arm is outside the host.

One child process holds the emulated firmware on a pty and the MuJoCo physics it drives
(``worlds.MockPhysics``). The host talks to the arm only as it talks to a real one, through the
pty's serial bytes, plus a small control channel for what only a simulator can do: place and
clear objects, the truth for judging success (published in shared memory after every physics
step, so the control loop reads it without waiting), and what tests inspect (the commands the
device applied, an unplugged cable). The scene state goes to the free-running cameras' render
process through their shared state block.

Why a process: in the host, the emulator and physics threads shared the control loop's GIL and
woke it late. Here they cannot hold its GIL, and they run at a lower priority than the host's
loop (``nice``, or real-time below the loop's where the loop has it), as the render process does.

Lifecycle: ``MockArmProcess`` is a ``PtyDevice`` (a context manager; ``port`` is the pty). The
child is stopped over the channel and killed if it does not exit; it exits by itself when the
host dies (the channel's socket closes under it). A child that dies while the host runs makes
every later call, ``truth()`` and the backend's exit raise one line naming how it died.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from multiprocessing import shared_memory
from multiprocessing.connection import Connection
from types import TracebackType
from typing import Any

import numpy as np

from hardware.emulator.lifecycle import PtyDevice
from hardware.emulator.server import EmulatorConfig
from hardware.errors import HardwareError
from hardware.plant import Plant
from sim2real.camera_rig import RigSpec
from sim2real.deploy.child import child_env, death_line, one_line

log = logging.getLogger(__name__)

# truth block (float64): [lock, t_s, grasped (-1: no cube), physics steps, tool xyz, arm-table
# contact steps], then per object of TRUTH_KEYS [present, x, y, z]
TRUTH_KEYS = ("target", "cube", "seam_start", "seam_end")
_TRUTH_HEADER = 8
_TRUTH_SIZE = _TRUTH_HEADER + 4 * len(TRUTH_KEYS)


@dataclass(frozen=True)
class MockArmJob:
    """Everything the child needs to become the arm (pickled over the channel)."""

    plant: Plant  # the arm as it is (watchdog already relaxed where the backend asked)
    scene: str
    protocol: str = "s2r"
    firmware: str = "python"  # a ``hardware.emulator.FIRMWARES`` name
    emulator_config: EmulatorConfig = field(default_factory=EmulatorConfig)
    rig: RigSpec = field(default_factory=RigSpec)
    state_block: str | None = None  # the render process's scene state block, if any
    # The whole process below the host: it yields to the control loop. One priority for all
    # its threads: they share one GIL, and an emulator thread above a physics thread would wait
    # for the GIL on a thread the machine's load keeps off the CPU (a second without a reply,
    # measured under pytest on a loaded machine with the physics thread at +5).
    nice: int = 5
    switch_interval_s: float | None = None  # the child's GIL switch interval (None: Python's)
    # SCHED_FIFO for the whole process (every thread inherits it), below the host loop's
    # CONTROL_PRIORITY: on a loaded machine the arm still answers its serial bytes, as a real
    # arm's own controller does, and the physics thread, which holds the process's GIL, is not
    # preempted by normal jobs while the emulator waits for it. None: normal scheduling.
    realtime_priority: int | None = None


def _write_truth(
    block: np.ndarray, t_s: float, truth: Any, steps: int, table_contacts: int
) -> None:
    tool, objects, grasped = truth
    block[0] += 1  # odd: writing
    block[1] = t_s
    block[2] = -1.0 if grasped is None else float(bool(grasped))
    block[3] = steps
    block[4:7] = tool
    block[7] = table_contacts
    for i, key in enumerate(TRUTH_KEYS):
        o = _TRUTH_HEADER + 4 * i
        pos = objects.get(key)
        block[o] = 0.0 if pos is None else 1.0
        if pos is not None:
            block[o + 1 : o + 4] = pos
    block[0] += 1  # even: done


def _read_truth(block: np.ndarray) -> np.ndarray | None:
    """A consistent copy, or None while the writer is busy (it may be preempted mid-write)."""
    for _ in range(100):
        s1 = block[0]
        if s1 % 2 == 1:
            continue
        copy = block.copy()
        if block[0] == s1:
            return copy
    return None


class MockArmProcess(PtyDevice):
    """The host's handle on the mock arm's process: its pty, its control channel, its truth."""

    START_TIMEOUT_S = 120.0  # importing MuJoCo on a loaded machine (start-up, before torque)
    CALL_TIMEOUT_S = 60.0
    STOP_TIMEOUT_S = 5.0

    def __init__(self, job: MockArmJob) -> None:
        self.job = job
        self.link = None
        self.device_path = ""
        self._running = False
        self._proc: subprocess.Popen[bytes] | None = None
        self._conn: Connection | None = None
        self._call_lock = threading.Lock()
        self._stderr: Any = None
        self._stopping = self._stopping_sent = False
        self._final: dict[str, Any] = {}  # what the child said last (its log), for after stop
        self._truth_shm: shared_memory.SharedMemory | None = None
        self._truth: np.ndarray | None = None
        self._last_truth: np.ndarray | None = None
        self.info: dict[str, Any] = {}

    # ---- lifecycle --------------------------------------------------------------------------
    def start(self) -> str:
        """Start the child (``python -m sim2real.deploy.mock_arm``: a spawned multiprocessing
        child would re-import the user's ``__main__``) and wait until it serves the pty."""
        if self._running:
            return self.port
        self._truth_shm = shared_memory.SharedMemory(create=True, size=8 * _TRUTH_SIZE)
        self._truth = np.ndarray((_TRUTH_SIZE,), np.float64, self._truth_shm.buf)
        self._truth[:] = 0.0
        self._truth[1] = -1.0  # nothing published yet
        # the child's last words, for a one-line error; closed by stop()
        self._stderr = tempfile.TemporaryFile()  # noqa: SIM115
        ours, theirs = socket.socketpair()
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "sim2real.deploy.mock_arm", str(theirs.fileno())],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,  # nothing of the child's may land in a --json stdout
                stderr=self._stderr,
                pass_fds=(theirs.fileno(),),
                close_fds=True,
                env=child_env(),  # single-threaded BLAS: no worker thread to wait on
            )
        finally:
            theirs.close()
        self._conn = Connection(ours.detach())
        self._stopping = self._stopping_sent = False
        try:
            self._conn.send((self.job, self._truth_shm.name))
            self.info = self._reply("start", self.START_TIMEOUT_S)
        except BaseException:
            self.stop()
            raise
        self.device_path = str(self.info["port"])
        if self.job.realtime_priority is not None and not self.info.get("realtime"):
            log.warning("mock arm at normal priority: real-time scheduling refused")
        self._running = True
        return self.port

    def stop(self) -> None:
        """Ask the child to exit, kill it if it does not; release everything. Idempotent."""
        self._running = False
        proc, conn = self._proc, self._conn
        if proc is not None:
            if proc.poll() is None and conn is not None and not self._stopping_sent:
                self._stopping_sent = True
                with contextlib.suppress(OSError, ValueError, EOFError, HardwareError):
                    conn.send(("stop", ()))
                    self._final = self._reply("stop", self.STOP_TIMEOUT_S, alive=False)
            try:
                proc.wait(timeout=self.STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=self.STOP_TIMEOUT_S)
        self._stopping = True
        if conn is not None:
            conn.close()
            self._conn = None
        if self._truth_shm is not None:
            self._truth = None
            self._truth_shm.close()
            with contextlib.suppress(FileNotFoundError):
                self._truth_shm.unlink()
            self._truth_shm = None
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """A run that failed because the arm's process died says so, in one line (the serial
        error it caused says only that the port went away)."""
        died = self.death()
        self.stop()
        if exc is not None and died is not None and not isinstance(exc, KeyboardInterrupt):
            raise HardwareError(died) from exc

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    def death(self) -> str | None:
        """One line saying how the child died, or None while it lives (or was stopped)."""
        if self._proc is None or self._stopping:
            return None
        return death_line("mock arm process", self._proc.poll(), self._stderr)

    def check_alive(self) -> None:
        died = self.death()
        if died is not None:
            raise HardwareError(died)

    # ---- the control channel ----------------------------------------------------------------
    def _reply(self, op: str, timeout_s: float, alive: bool = True) -> Any:
        assert self._conn is not None and self._proc is not None
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                if self._conn.poll(0.05):
                    status, value = self._conn.recv()
                    break
            except (EOFError, OSError):  # the channel closed: the child is dying
                with contextlib.suppress(subprocess.TimeoutExpired):
                    self._proc.wait(timeout=self.STOP_TIMEOUT_S)
                if not alive:
                    raise HardwareError(f"the mock arm process closed the channel ({op})") from None
            if alive:
                self.check_alive()
            if time.monotonic() > deadline:
                raise HardwareError(f"the mock arm process did not answer {op!r} in {timeout_s} s")
        if status != "ok":
            raise HardwareError(f"mock arm: {op} failed: {value}")
        return value

    def call(self, op: str, *args: Any) -> Any:
        """Run one of ``OPS`` in the child and return its result (between periods: it waits)."""
        self.check_alive()
        if self._conn is None:
            raise HardwareError("the mock arm process is not running")
        with self._call_lock:
            self._conn.send((op, args))
            return self._reply(op, self.CALL_TIMEOUT_S)

    def truth(self) -> tuple[np.ndarray, dict[str, np.ndarray], bool | None]:
        """The newest physics state's truth (tool, objects, grasp), without waiting."""
        self.check_alive()
        assert self._truth is not None
        block = _read_truth(self._truth)
        if block is None:  # the writer was preempted mid-write: the previous state is whole
            block = self._last_truth
        if block is None or block[1] < 0.0:
            raise HardwareError("the mock arm process published no state")
        self._last_truth = block
        objects = {}
        for i, key in enumerate(TRUTH_KEYS):
            o = _TRUTH_HEADER + 4 * i
            if block[o] > 0.5:
                objects[key] = block[o + 1 : o + 4].copy()
        grasped = None if block[2] < 0 else bool(block[2] > 0.5)
        return block[4:7].copy(), objects, grasped

    # ---- what tests and benches ask of the emulated device ------------------------------------
    @property
    def firmware(self) -> str:
        """The class serving the pty in the child (``Emulator`` or ``AvrEmulator``)."""
        return str(self.info.get("emulator", ""))

    def applied(self, kind: str | None = None) -> list[Any]:
        """Every command the device applied (after ``stop``: its log at the end)."""
        if not self._running and "applied" in self._final:
            return [e for e in self._final["applied"] if kind is None or e.kind == kind]
        return list(self.call("applied", kind))

    def unplug(self) -> None:
        """The USB cable is pulled: the port goes away under the host (the process lives on)."""
        self.call("unplug")

    def true_positions_rad(self) -> np.ndarray:
        return np.asarray(self.call("true_positions_rad"), dtype=float)

    def stats(self) -> dict[str, Any]:
        return dict(self.call("stats"))

    def physics_steps(self) -> int:
        assert self._truth is not None
        return int(self._truth[3])

    def table_contacts(self) -> int | None:
        """Physics steps so far with an arm link touching the table (``MockPhysics``); after
        ``stop``, the count at the end (None if the child died without saying)."""
        if self._truth is not None:
            return int(self._truth[7])
        final = self._final.get("table_contacts")
        return None if final is None else int(final)


# ---- the child ----------------------------------------------------------------------------------
def _make_emulator(job: MockArmJob) -> Any:
    """The plant's emulator: the Python firmware model, or a firmware binary (``FIRMWARES``)."""
    if job.firmware == "python":
        return job.plant.emulator(job.protocol, job.emulator_config)
    from hardware.emulator import FIRMWARES

    return FIRMWARES[job.firmware](
        job.plant.spec,
        job.protocol,
        job.plant.emulator_config(job.emulator_config),
        mounting=job.plant.mounting(job.protocol),
    )


def _serve(conn: Connection, truth_name: str, job: MockArmJob, realtime: bool) -> None:
    from sim2real.deploy.render_process import SceneStatePublisher, attach_block
    from sim2real.deploy.worlds import MockPhysics

    emulator = _make_emulator(job)
    emulator.start()
    truth_shm = attach_block(truth_name)
    truth: np.ndarray = np.ndarray((_TRUTH_SIZE,), np.float64, truth_shm.buf)

    def die(exc: BaseException) -> None:  # the physics thread failed: the arm is gone
        print(f"mock physics stopped: {one_line(exc)}", file=sys.stderr, flush=True)
        os._exit(3)

    physics = MockPhysics(job.plant.spec, job.scene, emulator, job.rig, on_error=die)
    scene = None
    if job.state_block is not None:
        scene = SceneStatePublisher(job.state_block, physics.model.nq, physics.model.nmocap)

    def sink(t_s: float, data: Any, now_truth: Any) -> None:
        _write_truth(truth, t_s, now_truth, physics.steps, physics.table_contacts)
        if scene is not None:
            scene.publish(t_s, data.qpos, data.mocap_pos, data.mocap_quat)

    physics.sink = sink
    physics.start()
    ops: dict[str, Any] = {
        "place": physics.new_episode,
        "clear": physics.clear,
        "applied": lambda kind=None: emulator.applied(kind),
        "unplug": lambda: emulator.unplug(),
        "true_positions_rad": lambda: np.asarray(emulator.true_positions_rad()),
        "stats": lambda: emulator.stats(),
    }
    info = {"port": emulator.port, "emulator": type(emulator).__name__, "realtime": realtime}
    conn.send(("ok", info))
    try:
        while True:
            try:
                op, args = conn.recv()
            except (EOFError, OSError):
                break  # the host is gone: so is the arm
            if op == "stop":  # its last words: the device's log, for tests after the run
                final = {"applied": emulator.applied(), "table_contacts": physics.table_contacts}
                conn.send(("ok", final))
                break
            try:
                if op not in ops:
                    raise KeyError(f"unknown op {op!r}; valid: {sorted(ops)}")
                conn.send(("ok", ops[op](*args)))
            except Exception as exc:
                conn.send(("error", one_line(exc)))
    finally:
        physics.close()
        emulator.stop()
        if scene is not None:
            scene.close()
        with contextlib.suppress(BufferError):  # the process exits: the view may stay
            truth_shm.close()


def main() -> None:
    """The child's entry point: the channel's fd is the argument; the job its first message."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the host handles Ctrl-C, then stops us
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")
    conn = Connection(int(sys.argv[1]))
    job, truth_name = conn.recv()
    with contextlib.suppress(OSError):
        os.nice(job.nice)
    if job.switch_interval_s is not None:
        sys.setswitchinterval(job.switch_interval_s)
    realtime = False
    if job.realtime_priority is not None:  # before any thread starts: they all inherit it
        with contextlib.suppress(OSError, AttributeError):
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(job.realtime_priority))
            realtime = True
    try:
        _serve(conn, truth_name, job, realtime)
    except Exception as exc:  # start-up failed: the host raises this line
        with contextlib.suppress(OSError):
            conn.send(("error", one_line(exc)))
        raise


if __name__ == "__main__":
    main()
