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

Lifecycle (``child.ChildProcess``): ``MockArmProcess`` is a ``PtyDevice`` (a context manager;
``port`` is the pty). The child is stopped over the channel and killed if it does not exit; it
dies with the host. A child that dies while the host runs makes every later call, ``truth()``
and the backend's exit raise one line naming how it died.
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hardware.emulator.lifecycle import PtyDevice
from hardware.emulator.server import EmulatorConfig
from hardware.errors import HardwareError
from hardware.plant import Plant
from sim2real.camera_rig import RigSpec
from sim2real.deploy.child import (
    CRASH_EXIT,
    ChildChannel,
    ChildProcess,
    SharedBlock,
    one_line,
    read_consistent,
    run_child,
    seqlock,
    serve_requests,
)

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
    with seqlock(block):
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
        self._child: ChildProcess | None = None
        self._truth_block: SharedBlock | None = None
        self._truth: np.ndarray | None = None
        self._last_truth: np.ndarray | None = None
        self._final: dict[str, Any] = {}  # what the child said last (its log), for after stop
        self.info: dict[str, Any] = {}

    # ---- lifecycle --------------------------------------------------------------------------
    def start(self) -> str:
        """Start the child and wait until it serves the pty."""
        if self._running:
            return self.port
        self._truth_block = SharedBlock(8 * _TRUTH_SIZE)
        self._truth = self._truth_block.array(_TRUTH_SIZE)
        self._truth[:] = 0.0
        self._truth[1] = -1.0  # nothing published yet
        self._child = ChildProcess(
            "mock arm process", "sim2real.deploy.mock_arm", (self.job, self._truth_block.name),
            start_timeout_s=self.START_TIMEOUT_S, call_timeout_s=self.CALL_TIMEOUT_S,
            stop_timeout_s=self.STOP_TIMEOUT_S, nice=self.job.nice,
        )  # fmt: skip
        try:
            self.info = dict(self._child.start())
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
        if self._child is not None:
            final = self._child.stop()
            if isinstance(final, dict):
                self._final = final
        if self._truth_block is not None:
            self._truth = None
            self._truth_block.close()
            self._truth_block = None

    def __exit__(self, *exc_info: Any) -> None:
        """A run that failed because the arm's process died says so, in one line (the serial
        error it caused says only that the port went away)."""
        try:
            if self._child is not None:
                self._child.finish(exc_info[1])
        finally:
            self.stop()

    @property
    def pid(self) -> int | None:
        return None if self._child is None else self._child.pid

    def death(self) -> str | None:
        """One line saying how the child died, or None while it lives (or was stopped)."""
        return None if self._child is None else self._child.death()

    def check_alive(self) -> None:
        if self._child is not None:
            self._child.check_alive()

    def call(self, op: str, *args: Any) -> Any:
        """Run one of the child's ops and return its result (between periods: it waits)."""
        if self._child is None:
            raise HardwareError("the mock arm process is not running")
        return self._child.call(op, *args)

    def truth(self) -> tuple[np.ndarray, dict[str, np.ndarray], bool | None]:
        """The newest physics state's truth (tool, objects, grasp), without waiting."""
        self.check_alive()
        truth = self._truth
        assert truth is not None
        block = read_consistent(truth, truth.copy)
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

    def brownout(self) -> None:
        """Fault injection: the board's supply dips and it reboots (torque off, RAM lost)."""
        self.call("brownout")

    def jam(self, *names: str) -> None:
        """Fault injection: the named servos jam where their horns are (none: all free)."""
        self.call("jam", *names)

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


def _serve(channel: ChildChannel) -> dict[str, Any]:
    """Become the arm: the emulator on a pty, the physics it drives, the truth published after
    every step; serve the host's ops until it stops us. Returns the device's log."""
    from sim2real.deploy.render_process import SceneStateBlock
    from sim2real.deploy.worlds import MockPhysics

    job, truth_name = channel.job
    realtime = _scheduling(job)
    emulator = _make_emulator(job)
    emulator.start()
    truth_block = SharedBlock(name=truth_name)
    truth = truth_block.array(_TRUTH_SIZE)

    def die(exc: BaseException) -> None:  # the physics thread failed: the arm is gone
        print(f"mock physics stopped: {one_line(exc)}", file=sys.stderr, flush=True)
        os._exit(CRASH_EXIT)

    physics = MockPhysics(job.plant.spec, job.scene, emulator, job.rig, on_error=die)
    scene = None
    if job.state_block is not None:
        scene = SceneStateBlock(physics.model.nq, physics.model.nmocap, job.state_block)

    def sink(t_s: float, data: Any, now_truth: Any) -> None:
        _write_truth(truth, t_s, now_truth, physics.steps, physics.table_contacts)
        if scene is not None:
            scene.publish(t_s, data.qpos, data.mocap_pos, data.mocap_quat)

    physics.sink = sink
    physics.start()
    try:
        channel.ready({"port": emulator.port, "emulator": type(emulator).__name__,
                       "realtime": realtime})  # fmt: skip
        serve_requests(channel, _ops(emulator, physics))
        # its last words: the device's log, for tests after the run
        return {"applied": emulator.applied(), "table_contacts": physics.table_contacts}
    finally:
        physics.close()
        emulator.stop()
        if scene is not None:
            scene.close()
        truth_block.close()  # the process exits: a view still held may stay


def _ops(emulator: Any, physics: Any) -> dict[str, Callable[..., Any]]:
    """What the host may ask of the simulated arm (and what only a simulator can do)."""
    return {
        "place": physics.new_episode,
        "clear": physics.clear,
        "applied": lambda kind=None: emulator.applied(kind),
        "unplug": lambda: emulator.unplug(),
        "brownout": lambda: emulator.brownout(),
        "jam": lambda *names: emulator.jam(*names),
        "true_positions_rad": lambda: np.asarray(emulator.true_positions_rad()),
        "torque_enabled": lambda: np.asarray(emulator.torque_enabled()),
        "sync": lambda timeout_s: emulator.sync(timeout_s),  # the host's bytes all taken in
        "stats": lambda: emulator.stats(),
    }


def _scheduling(job: MockArmJob) -> bool:
    """The GIL switch interval and SCHED_FIFO of the job, before any thread starts (they all
    inherit it); whether real-time scheduling was granted."""
    if job.switch_interval_s is not None:
        sys.setswitchinterval(job.switch_interval_s)
    if job.realtime_priority is None:
        return False
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(job.realtime_priority))
    except (OSError, AttributeError):
        return False
    return True


def main() -> None:
    """The child's entry point (``run_child``: the channel's fd and the parent's pid)."""
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")
    run_child(_serve)


if __name__ == "__main__":
    main()
