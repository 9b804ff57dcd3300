"""One way to run a part of the runtime in a process of its own: the mock arm, the renderer,
perception and the learner.

Why processes: a thread of the control process shares its GIL, and at a lower priority it is
preempted while holding it, so the loop, awake on time, waits for it. A child has its own GIL.

The parent's ``ChildProcess`` and the child's ``run_child`` hold what they all share:

- **start**: ``python -m <module>`` (not multiprocessing: a spawned child re-imports the user's
  ``__main__``), in its own process group (the terminal's Ctrl-C reaches the parent, which stops
  the arm first, then its children), with single-threaded BLAS, stdout closed (nothing of the
  child's may land in a ``--json`` stdout) and stderr kept for its last words;
- **a channel**: a socket pair; the job is its first message, then requests (``call`` waits for
  the answer, ``post`` does not and never blocks the loop), in order;
- **ready**: ``start`` returns the child's ``ready`` message (or raises its one-line error);
- **signals, set explicitly in the child** (an ignored SIGINT is inherited, NOTES.md, and so is
  SCHED_FIFO): SIGINT and SIGTERM ignored, normal scheduling, the job's niceness;
- **crash**: one line, ``the <what> died (exit 3): <its last stderr line>``;
- **shutdown**: ``stop`` asks over the channel, waits, then kills; the child dies with its
  parent (``PR_SET_PDEATHSIG``, and the channel's end of file), so nothing is left orphaned.

``SharedBlock`` is the shared memory they publish in, and ``seqlock``/``read_consistent`` the one
sequence lock over it: the writer makes the lock odd while it writes, the reader copies and
keeps the copy only if the lock was even and unchanged, so it never waits and never takes half
a write.
"""

from __future__ import annotations

import contextlib
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from multiprocessing import resource_tracker, shared_memory
from multiprocessing.connection import Connection
from typing import IO, Any, TypeVar

import numpy as np

from hardware.errors import HardwareError

T = TypeVar("T")

# numpy's BLAS (OpenBLAS here) and the OpenMP runtimes read these when they load
ONE_THREAD_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
CRASH_EXIT = 3  # a child that failed: its one line is the last line of its stderr
_STOP = "__stop__"


def child_env() -> dict[str, str]:
    """The environment for a child of the control loop (the mock arm, render and perception
    processes): this one, with single-threaded BLAS and OpenMP (why:
    ``realtime.single_threaded_blas``)."""
    return {**os.environ, **ONE_THREAD_ENV}


def one_line(exc: BaseException) -> str:
    """The child's last words: the exception's type and first line."""
    text = (str(exc).splitlines() or [""])[0]
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def death_line(what: str, rc: int | None, stderr: IO[bytes] | None) -> str | None:
    """``"the <what> died (<how>): <last stderr line>"``, or None while it runs (``rc`` None)."""
    if rc is None:
        return None
    how = f"killed by {signal.Signals(-rc).name}" if rc < 0 else f"exit {rc}"
    last = _last_words(stderr) if rc > 0 else ""  # a signal leaves no words of its own
    return f"the {what} died ({how})" + (f": {last}" if last else "")


def _last_words(stderr: IO[bytes] | None) -> str:
    if stderr is None:
        return ""
    with contextlib.suppress(OSError):
        stderr.seek(0, os.SEEK_END)
        stderr.seek(max(0, stderr.tell() - 4096))
        lines = stderr.read().decode(errors="replace").strip().splitlines()
        return lines[-1].strip() if lines else ""
    return ""


# ---- shared memory ------------------------------------------------------------------------------
_OWNED: set[str] = set()  # the blocks this process created: attached here too, e.g. a frame block


class SharedBlock:
    """Shared memory: created here (``name=None``: this process owns it and unlinks it on
    close) or another process's, attached by name (never unlinked here: Python's resource
    tracker would otherwise remove it under its owner when this process exits).

    Views from ``array`` must be dropped before ``close`` (numpy holds the buffer)."""

    def __init__(self, nbytes: int = 0, name: str | None = None) -> None:
        self.owner = name is None
        if name is None:
            self._shm = shared_memory.SharedMemory(create=True, size=max(nbytes, 1))
            _OWNED.add(self._shm._name)  # type: ignore[attr-defined]
        else:
            self._shm = shared_memory.SharedMemory(name=name)
            if self._shm._name not in _OWNED:  # type: ignore[attr-defined]
                # (its owner's registration, in this process, must stay: the tracker keeps
                # one entry a name, and the owner's unlink removes it)
                resource_tracker.unregister(self._shm._name, "shared_memory")  # type: ignore[attr-defined]
        self.closed = False

    @property
    def name(self) -> str:
        return str(self._shm.name)

    def array(self, shape: int | tuple[int, ...], dtype: Any = np.float64, offset: int = 0
              ) -> np.ndarray:  # fmt: skip
        return np.ndarray(shape, dtype, self._shm.buf, offset=offset)

    def close(self) -> None:
        """Unmap (and unlink, if ours). Idempotent; a view still held keeps the mapping alive
        until it goes (the block's name is gone either way)."""
        if self.closed:
            return
        self.closed = True
        with contextlib.suppress(BufferError):
            self._shm.close()
        if self.owner:
            _OWNED.discard(self._shm._name)  # type: ignore[attr-defined]
            with contextlib.suppress(FileNotFoundError):
                self._shm.unlink()


@contextlib.contextmanager
def seqlock(block: np.ndarray, at: int = 0) -> Iterator[None]:
    """Write under the sequence lock ``block[at]``: odd while writing, even when done."""
    block[at] += 1
    try:
        yield
    finally:
        block[at] += 1


def read_consistent(block: np.ndarray, copy: Callable[[], T], at: int = 0, tries: int = 100
                    ) -> T | None:  # fmt: skip
    """``copy()`` taken while no write was under way on ``block[at]``, or None if the writer
    held the lock on every try (it may be preempted mid-write: the caller keeps what it had)."""
    for _ in range(tries):
        before = block[at]
        if before % 2 == 1:
            continue
        value = copy()
        if block[at] == before:
            return value
    return None


# ---- the child's side ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Request:
    op: str
    args: tuple[Any, ...]
    wants_answer: bool  # a ``call`` (the parent waits) or a ``post``


class ChildChannel:
    """The child's end: the job, the ready message, the parent's requests and their answers."""

    def __init__(self, conn: Connection) -> None:
        self._conn = conn
        self.job: Any = conn.recv()
        self.stopping = False  # the parent asked us to stop, or is gone
        self._stop_asked = False

    def ready(self, info: Any = None) -> None:
        self._conn.send(("ready", info))

    def receive(self, timeout_s: float | None = None) -> Request | None:
        """The next request, or None: none within ``timeout_s`` (None: wait), or the parent
        asked us to stop or went away (then ``stopping`` is set)."""
        if self.stopping:
            return None
        try:
            if timeout_s is not None and not self._conn.poll(timeout_s):
                return None
            op, args, wants_answer = self._conn.recv()
        except (EOFError, OSError):  # the parent is gone: so are we
            self.stopping = True
            return None
        if op == _STOP:
            self.stopping = self._stop_asked = True
            return None
        return Request(op, tuple(args), bool(wants_answer))

    def stop_requested(self) -> bool:
        """Without waiting: a loop that serves no requests (render, perception) asks this."""
        self.receive(0.0)
        return self.stopping

    def answer(self, value: Any) -> None:
        self._conn.send(("ok", value))

    def fail(self, exc: BaseException) -> None:
        self._conn.send(("error", one_line(exc)))

    def goodbye(self, last_words: Any = None) -> None:
        """Answer the parent's stop (with what it should keep: a device's log)."""
        if self._stop_asked:
            with contextlib.suppress(OSError):
                self.answer(last_words)


def serve_requests(channel: ChildChannel, ops: Mapping[str, Callable[..., Any]]) -> None:
    """Run each request's op, in order, until stopped; a failed op is answered with its line."""
    while not channel.stopping:
        request = channel.receive()
        if request is None:
            continue
        try:
            if request.op not in ops:
                raise KeyError(f"unknown op {request.op!r}; valid: {sorted(ops)}")
            result = ops[request.op](*request.args)
        except Exception as exc:
            if not request.wants_answer:
                raise  # nobody would hear of it: the child dies and says so
            channel.fail(exc)
            continue
        if request.wants_answer:
            channel.answer(result)


def _die_with_parent() -> None:
    """SIGKILL when the parent dies (Linux), even if it dies by SIGKILL; elsewhere the
    channel's end of file ends the child."""
    if sys.platform.startswith("linux"):
        import ctypes

        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG


def run_child(serve: Callable[[ChildChannel], Any]) -> None:
    """A child's ``main``: signals and priority set explicitly, dies with its parent, then
    ``serve(channel)`` (which calls ``channel.ready``); its return value answers the parent's
    stop. A failure is one line on stderr and exit ``CRASH_EXIT``, which the parent raises."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)  # the parent decides: it parks the arm, then stops us
    _die_with_parent()
    fd, parent, nice = (int(a) for a in sys.argv[1:4])
    if os.getppid() != parent:  # it died before the prctl
        os._exit(1)
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))  # never inherit FIFO
    with contextlib.suppress(OSError):
        os.nice(nice)
    try:
        channel = ChildChannel(Connection(fd))
        channel.goodbye(serve(channel))
    except Exception as exc:
        print(one_line(exc), file=sys.stderr, flush=True)
        sys.exit(CRASH_EXIT)


# ---- the parent's side --------------------------------------------------------------------------
class ChildProcess:
    """The parent's handle on one child (``run_child`` in ``module``): start it and wait until it
    is ready, send it requests, notice its death, stop it. A context manager: a run that failed
    because the child died says so in one line."""

    def __init__(
        self,
        what: str,
        module: str,
        job: Any,
        *,
        start_timeout_s: float = 120.0,  # importing MuJoCo or torch on a loaded machine
        call_timeout_s: float = 60.0,
        stop_timeout_s: float = 5.0,
        nice: int = 0,  # below the control loop: the child yields to it
        error: type[Exception] = HardwareError,
    ) -> None:
        self.what, self.module, self.job, self.nice = what, module, job, nice
        self.start_timeout_s = start_timeout_s
        self.call_timeout_s = call_timeout_s
        self.stop_timeout_s = stop_timeout_s
        self.error = error
        self.info: Any = None  # what the child said when ready
        self.last_words: Any = None  # what it answered to ``stop``
        self._proc: subprocess.Popen[bytes] | None = None
        self._conn: Connection | None = None
        self._stderr: IO[bytes] | None = None
        self._outbox: queue.SimpleQueue[tuple[str, tuple[Any, ...], bool] | None] = (
            queue.SimpleQueue()
        )
        self._feeder: threading.Thread | None = None
        self._call_lock = threading.Lock()
        self._stopped = False
        self._ready = False

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    @property
    def running(self) -> bool:
        return self._proc is not None and not self._stopped and self._proc.poll() is None

    def start(self) -> Any:
        """Start the child and return its ``ready`` info; on any failure nothing is left."""
        self.launch()
        try:
            return self.wait_ready()
        except BaseException:
            self.stop()
            raise

    def launch(self) -> None:
        """Start the child and send its job, without waiting for it (``wait_ready`` does).

        Call it from a thread that outlives the child (the main thread): Linux's parent-death
        signal follows the thread that started it."""
        self._stderr = tempfile.TemporaryFile()  # noqa: SIM115 - closed by stop()
        self._stopped = self._ready = False
        ours, theirs = _socketpair()
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", self.module, str(theirs.fileno()), str(os.getpid()),
                 str(self.nice)],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=self._stderr,
                pass_fds=(theirs.fileno(),), close_fds=True, env=child_env(), process_group=0,
            )  # fmt: skip
        finally:
            theirs.close()
        self._conn = ours
        # the feeder is started here, by the caller, at its priority: not inside the loop's
        # real-time block (a thread started there would inherit SCHED_FIFO)
        self._feeder = threading.Thread(target=self._feed, name=f"{self.what} feeder", daemon=True)
        self._feeder.start()
        self._outbox.put(("job", (self.job,), False))

    def wait_ready(self, timeout_s: float | None = None) -> Any:
        """The child's ``ready`` info, once it is ready (its death or the timeout raise)."""
        if not self._ready:
            timeout = self.start_timeout_s if timeout_s is None else timeout_s
            self._answer("start", timeout, expect="ready")
        return self.info

    def _feed(self) -> None:
        """Send what ``post``, ``call`` and ``stop`` queued, in order (``post`` never waits)."""
        while True:
            message = self._outbox.get()
            if message is None or self._conn is None:
                return
            op, args, wants_answer = message
            try:
                if op == "job":
                    self._conn.send(args[0])
                else:
                    self._conn.send((op, args, wants_answer))
            except (OSError, ValueError):
                return  # the child is gone: its death is reported where it is noticed
            if op == _STOP:
                return

    def death(self) -> str | None:
        """One line saying how the child died, or None while it lives (or after ``stop``)."""
        if self._proc is None or self._stopped:
            return None
        return death_line(self.what, self._proc.poll(), self._stderr)

    def check_alive(self) -> None:
        died = self.death()
        if died is not None:
            raise self.error(died)

    def post(self, op: str, *args: Any) -> None:
        """A request the child does not answer, queued: the caller never waits."""
        self._outbox.put((op, args, False))

    def call(self, op: str, *args: Any, timeout_s: float | None = None) -> Any:
        """Run ``op`` in the child (after everything posted before it) and return its answer."""
        self.check_alive()
        if self._conn is None or self._stopped:
            raise self.error(f"the {self.what} is not running")
        with self._call_lock:
            self._outbox.put((op, args, True))
            return self._answer(op, self.call_timeout_s if timeout_s is None else timeout_s)

    def _answer(self, op: str, timeout_s: float, expect: str = "ok", alive: bool = True) -> Any:
        """The child's answer to ``op``; its death, an error or the timeout raise one line."""
        assert self._conn is not None and self._proc is not None
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                if self._conn.poll(0.05):
                    status, value = self._conn.recv()
                    if status == "ready":  # first, whether or not anyone waited for it
                        self.info, self._ready = value, True
                        if expect != "ready":
                            continue
                    break
            except (EOFError, OSError):  # the channel closed: the child is dying
                with contextlib.suppress(subprocess.TimeoutExpired):
                    self._proc.wait(timeout=self.stop_timeout_s)
                if not alive:
                    raise self.error(f"the {self.what} closed the channel ({op})") from None
            if alive:
                self.check_alive()
            if time.monotonic() > deadline:
                raise self.error(f"the {self.what} did not answer {op!r} in {timeout_s:g} s")
        if status != expect:
            raise self.error(f"{op} failed in the {self.what}: {value}")
        return value

    def stop(self) -> Any:
        """Ask the child to stop, kill it if it does not; release everything. Idempotent.
        Returns what it answered (``last_words``)."""
        proc, conn = self._proc, self._conn
        if proc is not None and not self._stopped:
            self._stopped = True
            if proc.poll() is None and conn is not None:
                self._outbox.put((_STOP, (), True))
                with contextlib.suppress(Exception):  # dying anyway: it is killed below
                    self.last_words = self._answer("stop", self.stop_timeout_s, alive=False)
            try:
                proc.wait(timeout=self.stop_timeout_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=self.stop_timeout_s)
        self._outbox.put(None)  # the feeder ends
        if self._feeder is not None:
            self._feeder.join(timeout=self.stop_timeout_s)
            self._feeder = None
        if conn is not None:
            conn.close()
            self._conn = None
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None
        return self.last_words

    def finish(self, exc: BaseException | None) -> None:
        """Stop the child after a run that raised ``exc`` (or None): a run that failed because
        the child died says so, in one line (the error its death caused elsewhere, a serial
        port gone, says less)."""
        died = self.death()
        self.stop()
        if exc is not None and died is not None and not isinstance(exc, KeyboardInterrupt):
            raise self.error(died) from exc

    def __enter__(self) -> ChildProcess:
        self.start()
        return self

    def __exit__(self, *exc_info: Any) -> None:
        self.finish(exc_info[1])


def _socketpair() -> tuple[Connection, Any]:
    import socket

    ours, theirs = socket.socketpair()
    return Connection(ours.detach()), theirs
