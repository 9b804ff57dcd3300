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
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
HANG_S = 300.0  # only turns a hang into a failed fault


def emit(metric: str, value: object, unit: str = "", **extra: object) -> None:
    print(json.dumps({"metric": metric, "value": value, "unit": unit, **extra}), flush=True)


def _default_signals() -> None:
    """A background job inherits SIGINT ignored: the child gets the dispositions a user's has."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_DFL)


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _descendants(pid: int) -> set[int]:
    parents: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    parents[int(entry)] = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
    found, frontier = set(), {pid}
    while frontier:
        children = {c for c, p in parents.items() if p in frontier} - found
        found |= children
        frontier = children
    return found


def _command(args: argparse.Namespace, out: Path, *extra: str) -> list[str]:
    return [
        sys.executable, "-m", "sim2real", "finetune", args.policy, "--backend", "mock",
        "--plant", args.plant, "--out", str(out), "--json", "--minutes", "30",
        "--learning-starts", "20", "--watchdog-s", str(args.watchdog_s),
        "--start-timeout", "120", *extra,
    ]  # fmt: skip


def _strike(fault: str, proc: subprocess.Popen[str], master: int | None) -> None:
    strikes: dict[str, Callable[[], None]] = {
        "sigint": lambda: proc.send_signal(signal.SIGINT),
        "sigterm": lambda: proc.send_signal(signal.SIGTERM),
        "sigkill": proc.kill,
        "estop": lambda: os.write(master, b"e") if master is not None else None,
    }
    strikes[fault]()


def run_fault(fault: str, args: argparse.Namespace, work: Path) -> dict[str, Any]:
    out = work / fault
    keys = ("--keys",) if fault == "estop" else ("--no-keys",)
    extra: tuple[str, ...] = ()
    if fault == "diverge":
        extra = ("--learning-rate", "0.5", "--utd", "1", "--actor-starts", "0",
                 "--noise-std", "1.0", "--max-episodes", str(args.diverge_episodes))  # fmt: skip
    cmd = _command(args, out, *keys, *extra)
    master = slave = None
    if fault == "estop":  # the keys come from a terminal: a real pty
        master, slave = os.openpty()
    proc = subprocess.Popen(
        cmd, cwd=ROOT, stdin=slave if slave is not None else subprocess.DEVNULL,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_signals,
    )  # fmt: skip
    if slave is not None:
        os.close(slave)
    reported, learner_pid, started = 0, None, set()
    struck_at = None
    summary: dict[str, Any] | None = None
    t0 = time.monotonic()
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            event = json.loads(line)
            if event["event"] == "learner_ready":
                learner_pid = event["learner_pid"]
            elif event["event"] == "episode":
                reported += 1
                if fault != "diverge" and reported == args.episodes_before:
                    time.sleep(args.strike_after_s)  # into the next episode
                    started = _descendants(proc.pid)
                    struck_at = time.monotonic()
                    _strike(fault, proc, master)
                    if fault == "sigkill":
                        break
            elif event["event"] == "summary":
                summary = event
            if time.monotonic() - t0 > HANG_S:
                proc.kill()
                break
        proc.wait(timeout=HANG_S)
        exit_s = None if struck_at is None else time.monotonic() - struck_at
        err = proc.stderr.read() if proc.stderr is not None else ""
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if master is not None:
            os.close(master)
    # what outlived the host (SIGKILL: the learner by its parent-death signal, the mock arm's
    # process when its control channel closes); waited for, then killed if still there
    deadline = time.monotonic() + 30.0
    while any(_alive(p) for p in started) and time.monotonic() < deadline:
        time.sleep(0.1)
    outlived = sorted(p for p in started if _alive(p))
    for pid in outlived:
        os.kill(pid, signal.SIGKILL)
    state = json.loads((out / "finetune.json").read_text())
    stop = state["stops"][-1] if state["stops"] else {}
    row: dict[str, Any] = {
        "fault": fault,
        "returncode": proc.returncode,
        "exit_after_fault_s": None if exit_s is None else round(exit_s, 2),
        "stop_reason": stop.get("reason") or (summary or {}).get("stopped"),
        "arm_end": stop.get("arm_end") or (summary or {}).get("arm_end"),
        "episodes_reported": reported,
        "episodes_checkpointed": state["episodes"],
        "finished_episodes_lost": reported - state["episodes"],
        "env_steps_checkpointed": state["env_steps"],
        "processes_outliving_host": len(outlived),
        "learner_outlived": learner_pid is not None and learner_pid in outlived,
        "stderr_tail": err.strip().splitlines()[-1][:200] if err.strip() else "",
    }
    if summary is not None:
        row["safety"] = summary.get("safety")
    if fault != "diverge":
        resumed = subprocess.run(
            [*cmd, "--resume", "--max-episodes", "1"], cwd=ROOT, capture_output=True, text=True,
            timeout=HANG_S, preexec_fn=_default_signals,
            stdin=subprocess.DEVNULL,
        )  # fmt: skip
        row["resume_returncode"] = resumed.returncode
        if resumed.returncode == 0:
            after = json.loads(resumed.stdout.strip().splitlines()[-1])
            row["resume_episodes"] = after["episodes"]
            row["resume_continues"] = (
                after["episodes"] == state["episodes"] + 1
                and after["env_steps"] > state["env_steps"]
            )
        else:
            row["resume_error"] = resumed.stderr.strip().splitlines()[-1][:200]
    return row


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
            row = run_fault(fault, args, Path(tmp))
            emit("finetune_fault", row["returncode"], "exit status", **row, **common)


if __name__ == "__main__":
    main()
