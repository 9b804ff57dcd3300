"""Faults mid-fine-tune on the mock arm: SIGINT, SIGTERM, SIGKILL, the e-stop key, a diverging
learner.

Each fault runs ``sim2real finetune`` as a user would (its own process, the mock arm built from a
plant preset, the learner process beside it), lets a few episodes finish, then strikes in the
middle of the next one. JSON lines, one per fault (``finetune_fault``):

- the exit status and the stop reason the run recorded (``finetune.json``);
- where the arm ended (``arm_end``: torque, joints, distance from the park pose), as the run read
  it back before its port closed (SIGKILL leaves no such record: the host is gone, and the mock
  arm's process and the learner die with it, checked in /proc);
- episodes: reported finished before the fault, checkpointed, and finished ones lost (the target
  is 0: only the episode in flight may be lost); then ``--resume --max-episodes 1`` must continue
  from the checkpoint (one more episode, more env steps).

The diverging learner (``diverge``) fine-tunes with a learning rate of 0.5, every transition a
gradient step and exploration noise 1.0 (saturated random actions): the workspace guard's
counters and the mock world's MuJoCo arm-table contacts (physics steps with a link on the table)
say whether the guard held it.

    PYTHONPATH=. .venv/bin/python bench/finetune_faults.py --plant hard
    PYTHONPATH=. .venv/bin/python bench/finetune_faults.py --faults sigterm sigkill
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from support.load import emit_row

ROOT = Path(__file__).resolve().parents[1]
HANG_S = 300.0  # only turns a hang into a failed fault


def emit(metric: str, value: object, unit: str = "", **extra: object) -> None:
    emit_row({"metric": metric, "value": value, "unit": unit, **extra})


def _default_signals() -> None:
    """A background job inherits SIGINT ignored: the child gets the dispositions a user's has."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_DFL)


def _group(pgid: int) -> set[int]:
    """Live processes of a process group (the run started its own session: the learner, the
    mock arm, render and perception processes are all in it), read from /proc."""
    found = set()
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    state, _ppid, pgrp = f.read().rsplit(")", 1)[1].split()[:3]
            except (OSError, ValueError):
                continue
            if int(pgrp) == pgid and state != "Z":
                found.add(int(entry))
    return found


def _kill_group(proc: subprocess.Popen[str]) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=10)


def _command(args: argparse.Namespace, out: Path, *extra: str) -> list[str]:
    return [
        sys.executable, "-m", "sim2real", "finetune", args.policy, "--backend", "mock",
        "--plant", args.plant, "--out", str(out), "--json", "--minutes", "30",
        "--learning-starts", "20", "--watchdog-s", str(args.watchdog_s),
        "--start-timeout", "120", *extra,
    ]  # fmt: skip


def _lines(stream: Any) -> queue.Queue[str | None]:
    """stdout's lines on a thread (None at its end), so that a silent run cannot hang the
    bench: the caller waits on the queue with a deadline."""
    lines: queue.Queue[str | None] = queue.Queue()

    def pump() -> None:
        for line in stream:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=pump, daemon=True).start()
    return lines


def _strike(fault: str, proc: subprocess.Popen[str], master: int | None) -> None:
    def estop_key() -> None:
        if master is not None:
            os.write(master, b"e")

    strikes: dict[str, Callable[[], None]] = {
        # a terminal's Ctrl-C reaches the whole foreground group; its children ignore it
        "sigint": lambda: os.killpg(proc.pid, signal.SIGINT),
        "sigterm": lambda: proc.send_signal(signal.SIGTERM),  # a scheduler stops the main pid
        "sigkill": proc.kill,
        "estop": estop_key,
    }
    strikes[fault]()


def _last_line(text: str) -> str:
    lines = text.strip().splitlines()
    return lines[-1][:200] if lines else ""


def run_fault(fault: str, args: argparse.Namespace, work: Path) -> dict[str, Any]:
    out = work / fault
    out.parent.mkdir(parents=True, exist_ok=True)
    keys = ("--keys",) if fault == "estop" else ("--no-keys",)
    extra: tuple[str, ...] = ()
    if fault == "diverge":
        extra = ("--learning-rate", "0.5", "--utd", "1", "--actor-starts", "0",
                 "--noise-std", "1.0", "--max-episodes", str(args.diverge_episodes))  # fmt: skip
    cmd = _command(args, out, *keys, *extra)
    row: dict[str, Any] = {"fault": fault}
    reported, struck_at, outlived = 0, None, set()
    summary: dict[str, Any] | None = None
    master = slave = None
    proc = None
    err_path = work / f"{fault}.stderr"
    try:
        if fault == "estop":  # the keys come from a terminal: a real pty
            master, slave = os.openpty()
        with open(err_path, "w") as err:
            proc = subprocess.Popen(
                cmd, cwd=ROOT, stdin=slave if slave is not None else subprocess.DEVNULL,
                stdout=subprocess.PIPE, stderr=err, text=True, preexec_fn=_default_signals,
                start_new_session=True,
            )  # fmt: skip
        if slave is not None:
            os.close(slave)
            slave = None
        assert proc.stdout is not None
        lines = _lines(proc.stdout)
        deadline = time.monotonic() + HANG_S
        while True:
            try:
                line = lines.get(timeout=max(0.1, deadline - time.monotonic()))
            except queue.Empty:
                row["error"] = f"no output for {HANG_S:g} s"
                break
            if line is None:
                break
            event = json.loads(line)
            if event["event"] == "episode":
                reported += 1
                if fault != "diverge" and reported == args.episodes_before:
                    time.sleep(args.strike_after_s)  # into the next episode
                    struck_at = time.monotonic()
                    _strike(fault, proc, master)
                    if fault == "sigkill":
                        break
            elif event["event"] == "summary":
                summary = event
        try:
            proc.wait(timeout=max(1.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            row["error"] = "the run did not exit"
        if struck_at is not None and proc.returncode is not None:
            row["exit_after_fault_s"] = round(time.monotonic() - struck_at, 2)
        # what outlives the host: SIGKILL leaves the learner to its parent-death signal and the
        # mock arm's process to its closed control channel
        gone_by = time.monotonic() + 30.0
        while _group(proc.pid) and time.monotonic() < gone_by:
            time.sleep(0.1)
        outlived = _group(proc.pid)
    finally:
        if proc is not None:
            _kill_group(proc)
        for fd in (master, slave):
            if fd is not None:
                os.close(fd)
    row["returncode"] = proc.returncode if proc is not None else None
    row["stderr_tail"] = _last_line(err_path.read_text()) if err_path.exists() else ""
    state = json.loads((out / "finetune.json").read_text())
    stop = state["stops"][-1] if state["stops"] else {}
    row.update(
        stop_reason=stop.get("reason") or (summary or {}).get("stopped"),
        arm_end=stop.get("arm_end") or (summary or {}).get("arm_end"),
        episodes_reported=reported,
        episodes_checkpointed=state["episodes"],
        finished_episodes_lost=reported - state["episodes"],
        env_steps_checkpointed=state["env_steps"],
        processes_outliving_host=len(outlived),
    )
    if summary is not None:
        row["safety"] = summary.get("safety")
    if fault != "diverge":
        row.update(_resume(cmd, state))
    return row


def _resume(cmd: list[str], state: dict[str, Any]) -> dict[str, Any]:
    """``--resume --max-episodes 1``: one more episode from the checkpoint (no terminal here:
    without the keys)."""
    cmd = ["--no-keys" if arg == "--keys" else arg for arg in cmd]
    proc = subprocess.Popen(
        [*cmd, "--resume", "--max-episodes", "1"], cwd=ROOT, stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=_default_signals, start_new_session=True,
    )  # fmt: skip
    try:
        stdout, stderr = proc.communicate(timeout=HANG_S)
    except subprocess.TimeoutExpired:
        return {"resume_error": f"no exit in {HANG_S:g} s"}
    finally:
        _kill_group(proc)
    out: dict[str, Any] = {"resume_returncode": proc.returncode}
    if proc.returncode != 0 or not stdout.strip():
        out["resume_error"] = _last_line(stderr)
        return out
    after = json.loads(stdout.strip().splitlines()[-1])
    out["resume_episodes"] = after["episodes"]
    out["resume_continues"] = (
        after["episodes"] == state["episodes"] + 1 and after["env_steps"] > state["env_steps"]
    )
    return out


def main() -> None:
    os.environ.setdefault("MUJOCO_GL", "egl")
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("policy", nargs="?", default="reach-ddpg")
    ap.add_argument("--plant", default="hard")
    ap.add_argument(
        "--faults", nargs="+", default=["sigint", "sigterm", "sigkill", "estop", "diverge"],
        choices=["sigint", "sigterm", "sigkill", "estop", "diverge"],
    )  # fmt: skip
    ap.add_argument("--episodes-before", type=int, default=3)
    ap.add_argument("--strike-after-s", type=float, default=1.2, help="into the next episode")
    ap.add_argument("--diverge-episodes", type=int, default=12)
    ap.add_argument("--watchdog-s", type=float, default=1.0)
    args = ap.parse_args()
    common = {"policy": args.policy, "plant": args.plant, "machine": platform.machine(),
              "cpus": os.cpu_count()}  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="finetune-faults-") as tmp:
        for fault in args.faults:
            try:
                row = run_fault(fault, args, Path(tmp))
            except Exception as exc:  # one fault's failure is its row, not the end of the bench
                row = {"fault": fault, "returncode": None, "error": f"{type(exc).__name__}: {exc}"}
            emit("finetune_fault", row["returncode"], "exit status", **row, **common)


if __name__ == "__main__":
    main()
