"""``sim2real finetune`` on the full mock chain: the emulator behind a real pty, MuJoCo driven by
its servos, rendered cameras, a spawned learner process with the SB3 model. The watchdog is
relaxed (``MOCK``) and nothing here asserts a rate, a period or a jitter."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from timescale import scaled

from hardware.spec import ArmSpec
from sim2real.cli.main import main
from sim2real.deploy.runner import DeployOptions
from sim2real.finetune.runner import FinetuneOptions, finetune

from .conftest import MOCK  # type: ignore[import-not-found]

ROOT = Path(__file__).resolve().parents[3]
HANG_S = scaled(240.0)  # only turns a hang into a failure


def _options(out: Path, **kw: Any) -> FinetuneOptions:
    base: dict[str, Any] = {
        "policy": "reach-ddpg",
        "out": out,
        "deploy": DeployOptions(**MOCK),
        "minutes": 10.0,
        "max_episodes": 1,
        "learning_starts": 20,
        "publish_every": 10,
        "keys": False,
        "start_timeout_s": scaled(60.0),
    }
    return FinetuneOptions(**{**base, **kw})


def _actor(zip_path: Path) -> np.ndarray:
    from sim2real.finetune.actor import actor_arrays, flatten
    from sim2real.train.algos import get_algo

    model = get_algo("ddpg").cls.load(  # type: ignore[attr-defined]
        str(zip_path), device="cpu", custom_objects={"buffer_size": 1}
    )
    return flatten(actor_arrays(model)[1])


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.realtime  # ~18 s idle: a mock episode with its learner process, export, evaluate
def test_mock_finetune_learns_within_limits_and_leaves_a_run_directory(
    tmp_path: Path, spec: ArmSpec, capsys: pytest.CaptureFixture[str]
) -> None:
    out, dataset = tmp_path / "ft", tmp_path / "ds"
    events: list[dict[str, Any]] = []
    first = finetune(_options(out, record_dataset=dataset), spec, events.append)
    assert first.stopped is None and first.episodes == 1
    steps = first.env_steps
    assert steps >= 1 and first.learner_updates > 0
    assert not _alive(next(e["learner_pid"] for e in events if e["event"] == "learner_ready"))

    # the actor the loop ran and the model the run dir carries both moved off the source
    from sim2real.policies import shipped

    source = shipped()["reach-ddpg"].checkpoint
    assert source is not None
    assert first.actor_weight_updates >= 1
    assert not np.allclose(_actor(out / "model.zip"), _actor(source[0]))

    # the guard and the joint limits held: every logged command is inside the spec's limits
    log = np.load(out / "episodes" / "episode_00000.npz")
    sent = log["sent_rad"]
    lower = np.array([j.lower_rad for j in spec.joints])
    upper = np.array([j.upper_rad for j in spec.joints])
    n = len(lower)
    assert len(sent) == steps
    assert np.all(sent[:, :n] >= lower - 1e-9) and np.all(sent[:, :n] <= upper + 1e-9)
    assert np.all(np.isfinite(sent))
    assert first.safety["nonfinite"] == 0
    assert first.safety["table_contacts"] == 0  # the mock world's MuJoCo saw no arm on the table
    # parked, torque off, read back before the port closed
    assert first.arm_end.torque_on is False and first.arm_end.park_error_rad < 0.05
    assert first.safety["commands"] >= steps

    # the learner trained on what the env saw: each transition is this period's observation
    # (normalised as the source run did), the action the policy chose, the reward with the
    # source's action-rate shaping, and the next period's observation (no off-by-one)
    from sim2real.finetune.actor import ObsNormalizer
    from sim2real.finetune.checkpoint import FinetuneDir, resolve

    state = json.loads((out / "finetune.json").read_text())
    model_ckpt = FinetuneDir(out).run.checkpoint_dir / state["checkpoint"]
    with np.load(model_ckpt.with_name(model_ckpt.stem + ".replay.npz")) as rep:
        replay = {k: rep[k] for k in ("obs", "next_obs", "actions", "rewards", "dones")}
    src = resolve("reach-ddpg", None)
    norm = ObsNormalizer.from_stats(src.obs_stats)
    assert norm is not None and len(replay["obs"]) == steps
    assert np.allclose(replay["obs"], np.stack([norm(o) for o in log["obs"]]), atol=1e-6)
    assert np.array_equal(replay["next_obs"][:-1], replay["obs"][1:])
    assert np.allclose(replay["actions"], log["action"], atol=1e-7)
    acts = np.asarray(log["action"], dtype=np.float64)
    prev = np.vstack([np.zeros((1, acts.shape[1])), acts[:-1]])
    shaped = log["reward"] - 0.5 * np.sum((acts - prev) ** 2, axis=1)
    assert np.allclose(replay["rewards"], shaped, atol=1e-5)
    assert not np.any(replay["dones"])  # reach never terminates: truncation bootstraps

    # the first run's episode as a LeRobot dataset, read back
    capsys.readouterr()
    assert main(["replay", str(dataset), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["episodes"] == 1

    # the output is a run directory: export and evaluate take it
    assert main(["export", str(out), "--check", "5", "--json"]) == 0
    assert (out / "policy.onnx").is_file()
    assert main(["evaluate", str(out), "--episodes", "2", "--json", "--no-progress"]) == 0


def _default_signals() -> None:
    """The child's own dispositions: a background job inherits SIGINT ignored (NOTES.md)."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_DFL)


@pytest.mark.slow
def test_sigterm_mid_finetune_exits_143_checkpoints_and_resumes(tmp_path: Path) -> None:
    out = tmp_path / "ft"
    cmd = [
        sys.executable, "-m", "sim2real", "finetune", "reach-ddpg", "--out", str(out),
        "--learning-starts", "20", "--watchdog-s", str(MOCK["watchdog_s"]),
        "--start-timeout", str(scaled(60)), "--json", "--no-keys", "--minutes", "10",
    ]  # fmt: skip
    proc = subprocess.Popen(
        cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=_default_signals, env={**os.environ, "MUJOCO_GL": "egl"},
    )  # fmt: skip
    learner_pid = None
    try:
        assert proc.stdout is not None
        deadline = time.monotonic() + HANG_S
        for line in proc.stdout:
            event = json.loads(line)
            if event["event"] == "learner_ready":
                learner_pid = event["learner_pid"]
            if event["event"] == "episode":  # one episode done: stop in the next one
                time.sleep(2.0)
                proc.send_signal(signal.SIGTERM)
                break
            assert time.monotonic() < deadline, "no episode finished"
        _, err = proc.communicate(timeout=HANG_S)
        assert proc.returncode == 143, err[-2000:]
        assert "interrupted (SIGTERM)" in err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if learner_pid is not None and _alive(learner_pid):
            os.kill(learner_pid, signal.SIGKILL)
            pytest.fail("the learner process outlived its parent")
    state = json.loads((out / "finetune.json").read_text())
    assert state["episodes"] >= 1 and state["stops"][-1]["reason"] == "SIGTERM"
    arm_end = state["stops"][-1]["arm_end"]  # parked mid-episode, then torque off
    assert arm_end["torque_on"] is False and arm_end["park_error_rad"] < 0.05, arm_end
    assert (out / "checkpoints" / state["checkpoint"]).is_file()
    steps = state["env_steps"]
    resumed = subprocess.run(
        [*cmd[:-2], "--minutes", "10", "--resume", "--max-episodes", "1"], cwd=ROOT,
        capture_output=True, text=True, timeout=HANG_S, preexec_fn=_default_signals,
    )  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    summary = json.loads(resumed.stdout.strip().splitlines()[-1])
    assert summary["episodes"] == state["episodes"] + 1 and summary["env_steps"] > steps


@pytest.mark.slow
def test_estop_key_through_a_pty_stops_the_arm_keeps_a_checkpoint(tmp_path: Path) -> None:
    out = tmp_path / "ft"
    cmd = [
        sys.executable, "-m", "sim2real", "finetune", "reach-ddpg", "--out", str(out),
        "--learning-starts", "20", "--watchdog-s", str(MOCK["watchdog_s"]),
        "--start-timeout", str(scaled(60)), "--json", "--keys", "--minutes", "10",
    ]  # fmt: skip
    master, slave = os.openpty()
    proc = subprocess.Popen(
        cmd, cwd=ROOT, stdin=slave, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=_default_signals,
    )  # fmt: skip
    os.close(slave)
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            if json.loads(line)["event"] == "episode":
                time.sleep(1.0)
                os.write(master, b"e")
                break
        stdout, err = proc.communicate(timeout=HANG_S)
        assert proc.returncode == 1, err[-2000:]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert "e-stop key" in summary["stopped"]
    state = json.loads((out / "finetune.json").read_text())
    assert [i["action"] for i in state["interventions"]] == ["estop"]
    assert (out / "checkpoints" / state["checkpoint"]).is_file()
    assert state["episodes"] >= 1


def _descendants(pid: int) -> set[int]:
    """Every process below ``pid`` (its mock arm, cameras, learner), read from /proc."""
    parents: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    parents[int(entry)] = int(f.read().rsplit(")", 1)[1].split()[1])
            except (FileNotFoundError, ProcessLookupError, IndexError, ValueError):
                continue
    found, frontier = set(), {pid}
    while frontier:
        children = {c for c, p in parents.items() if p in frontier} - found
        found |= children
        frontier = children
    return found


@pytest.mark.slow
def test_sigkill_mid_finetune_the_learner_dies_and_resume_loses_at_most_one_episode(
    tmp_path: Path,
) -> None:
    out = tmp_path / "ft"
    cmd = [
        sys.executable, "-m", "sim2real", "finetune", "reach-ddpg", "--out", str(out),
        "--learning-starts", "20", "--watchdog-s", str(MOCK["watchdog_s"]),
        "--start-timeout", str(scaled(60)), "--json", "--no-keys", "--minutes", "10",
    ]  # fmt: skip
    proc = subprocess.Popen(
        cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        preexec_fn=_default_signals,
    )  # fmt: skip
    started: set[int] = set()
    learner_pid = None
    reported = 0
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            event = json.loads(line)
            if event["event"] == "learner_ready":
                learner_pid = event["learner_pid"]
            if event["event"] == "episode":
                reported += 1
                if reported == 2:
                    time.sleep(1.0)  # mid-way into the next episode (or its start)
                    started = _descendants(proc.pid)
                    proc.kill()
                    break
        proc.wait(timeout=HANG_S)
        assert learner_pid is not None
        deadline = time.monotonic() + 30.0
        while _alive(learner_pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(learner_pid), "the learner outlived a SIGKILLed parent"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for pid in started:  # the mock arm and cameras, whatever happened
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
    state = json.loads((out / "finetune.json").read_text())
    assert state["episodes"] >= reported  # every finished episode was checkpointed first
    resumed = subprocess.run(
        [*cmd, "--resume", "--max-episodes", "1"], cwd=ROOT, capture_output=True, text=True,
        timeout=HANG_S, preexec_fn=_default_signals,
    )  # fmt: skip
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    summary = json.loads(resumed.stdout.strip().splitlines()[-1])
    assert summary["episodes"] == state["episodes"] + 1
    assert summary["env_steps"] > state["env_steps"]


def test_pick_finetunes_from_the_shipped_ddpg_paid_its_shaping_from_percepts_and_resumes(
    tmp_path: Path, spec: ArmSpec
) -> None:
    """pick-ddpg learns on SimArm's MuJoCo: the learner's rewards are the env's (goal term plus
    pick's shaping from percepts, no action-rate penalty: ddpg_pick has none) and its actor moves
    off the shipped one."""
    from sim2real.envs.base import REWARDS
    from sim2real.finetune.checkpoint import FinetuneDir
    from sim2real.policies import shipped

    out = tmp_path / "ft"
    sim = DeployOptions(backend="sim", sim_clock="lockstep")
    opts = _options(out, policy="pick-ddpg", deploy=sim, max_episodes=2)
    summary = finetune(opts, spec)
    assert summary.stopped is None and summary.episodes == 2
    assert summary.relabel == 0.0  # pick's goal is not relabelled
    source = shipped()["pick-ddpg"].checkpoint
    assert source is not None and summary.learner_updates > 0
    assert not np.allclose(_actor(out / "model.zip"), _actor(source[0]))
    logs = [np.load(out / "episodes" / f"episode_{k:05d}.npz") for k in range(2)]
    state = json.loads((out / "finetune.json").read_text())
    ckpt = FinetuneDir(out).run.checkpoint_dir / state["checkpoint"]
    with np.load(ckpt.with_name(ckpt.stem + ".replay.npz")) as rep:
        rewards = rep["rewards"]
    logged = np.concatenate([log["reward"] for log in logs])
    assert np.allclose(rewards, logged, atol=1e-5)
    # the shaping is paid: the reward is not the goal term of the perceived distance alone
    from sim2real.deploy.policy_io import io_for
    from sim2real.envs.base import TASKS

    goal_delta = io_for(spec, "Sim2Real/Arm3Pick-v0").builder.split(logs[0]["obs"])["goal_delta"]
    d = np.linalg.norm(goal_delta[1:], axis=1)  # a step's reward is on the next observation
    goal_term = np.asarray(REWARDS[TASKS["pick"].default_reward](d, d < 0.02))
    assert np.max(np.abs(logs[0]["reward"][:-1] - goal_term)) > 0.05

    # resume continues the counters (steps, episodes and updates go on), not restart, and the
    # learner takes the online transitions back
    second = finetune(_options(out, policy="pick-ddpg", deploy=sim, resume=True), spec)
    assert second.episodes == 3 and second.episodes_this_run == 1
    assert second.env_steps > summary.env_steps
    assert second.learner_updates >= summary.learner_updates
    assert (out / "episodes" / "episode_00002.npz").is_file()
    state = json.loads((out / "finetune.json").read_text())
    assert state["segments"] == 2 and state["env_steps"] == second.env_steps
    assert [e["episode"] for e in state["episode_log"]] == [0, 1, 2]
    assert state["online_transitions"] == second.env_steps


@pytest.mark.parametrize(
    ("backend", "recovers"), [("mock", True), ("sim", True), ("serial", False)]
)
def test_a_stall_loses_the_episode_on_a_simulated_arm_and_stops_a_real_one(
    tmp_path: Path, spec: ArmSpec, backend: str, recovers: bool
) -> None:
    """An exploring pick policy pressing the fingers on the cube stalls a joint: the arm holds,
    then parks itself, and on the mock or sim arm the episode is lost and learning goes on (three
    in a row stop it); on a real arm a person looks first, so the run stops."""
    from hardware.errors import StallError
    from sim2real.finetune.runner import MAX_CONSECUTIVE_TRIPS, _Run

    opts = {"mock": DeployOptions(**MOCK), "sim": DeployOptions(backend="sim"),
            "serial": DeployOptions(backend="serial", port="/dev/null")}[backend]  # fmt: skip
    run = _Run(_options(tmp_path / "ft", deploy=opts), spec, lambda event: None)
    stall = StallError("stall: shoulder is 0.149 rad from its command and has not moved")
    if not recovers:
        with pytest.raises(StallError, match="^stall: shoulder"):
            run._recover(stall, None, time.monotonic())
        return
    for _ in range(MAX_CONSECUTIVE_TRIPS):
        run._recover(stall, None, time.monotonic())
    stops = run.state["stops"]
    assert [s["recovered"] for s in stops] == [True] * MAX_CONSECUTIVE_TRIPS
    assert stops[0]["reason"].startswith("StallError: stall: shoulder")
    assert run.watchdog_trips == 0  # a stall is not a watchdog trip
    with pytest.raises(StallError):  # the next in a row stops the run
        run._recover(stall, None, time.monotonic())


def test_a_firmware_watchdog_trip_on_a_simulated_arm_is_a_lost_episode(
    tmp_path: Path, spec: ArmSpec
) -> None:
    """A starved host lets the firmware's watchdog put the torque off mid-episode: the next
    command is refused ("torque is off"); on the mock arm that episode is lost and counted as
    a trip, any other refusal stops the run."""
    from hardware.errors import SafetyError, TorqueOffError
    from sim2real.finetune.runner import _Run

    run = _Run(_options(tmp_path / "ft"), spec, lambda event: None)
    run._recover(TorqueOffError("torque is off: call enable() (or home()) before command()"), None,
                 time.monotonic())  # fmt: skip
    assert run.watchdog_trips == 1 and run.state["stops"][0]["recovered"] is True
    with pytest.raises(SafetyError, match="e-stop latched"):
        run._recover(SafetyError("e-stop latched by the e-stop key"), None, time.monotonic())
