"""Shared pieces for deploy tests: scripted policies that speak the observation contract."""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from timescale import scaled  # type: ignore[import-not-found]

from hardware.spec import ArmSpec, load_spec
from sim2real.deploy.policy_io import PolicyIO, io_for
from sim2real.deploy.runner import DeployOptions
from sim2real.observation import ActionDecoder, ObservationBuilder

# Behaviour is judged on SimArm's lockstep clock: one 20 Hz control period of physics per
# command, whatever the machine's load or the loop's wall rate. ``FAST`` paces the loop at
# 100 Hz of wall clock (as bench/pick_gap.py does): the episode is the same, only sooner.
LOCKSTEP = DeployOptions(backend="sim", sim_clock="lockstep")
FAST = {"rate_hz": 100.0}
# The mock chain (the realtime tests): its host and firmware watchdogs relaxed for a loaded
# machine, and wider still with SIM2REAL_TIME_SCALE. The cameras at the loop's 20 Hz, a frame a
# period: a fifth less of the chain's CPU than the default 30 fps (rendering and detection), a
# core the other pytest worker gets back.
MOCK = {"backend": "mock", "watchdog_s": scaled(2.0), "camera_fps": 20.0}


@pytest.fixture(scope="session")
def spec() -> ArmSpec:
    return load_spec()


@pytest.fixture(scope="session")
def reach_io(spec: ArmSpec) -> PolicyIO:
    return io_for(spec, "Sim2Real/Arm3Reach-v0")


@pytest.fixture(scope="session")
def pick_io(spec: ArmSpec) -> PolicyIO:
    return io_for(spec, "Sim2Real/Arm3Pick-v0")


@pytest.fixture(scope="session")
def reach_contract(reach_io: PolicyIO) -> tuple[ObservationBuilder, ActionDecoder]:
    return reach_io.builder, reach_io.decoder


def ik_policy(
    spec: ArmSpec, builder: ObservationBuilder, decoder: ActionDecoder, gain: float = 0.4
) -> Callable[[np.ndarray], np.ndarray]:
    """Reads joints and the goal estimate from the observation by the documented layout and
    servoes towards the IK solution: a policy that only works if the contract holds."""
    sl = {f.name: slice(f.start, f.stop) for f in builder.layout()}

    def policy(obs: np.ndarray) -> np.ndarray:
        q = obs[sl["joint_pos"]]
        q_goal = spec.inverse_kinematics(obs[sl["goal_pos"]])
        if q_goal is None:
            return np.zeros(decoder.n_actions)
        return np.clip(gain * (q_goal - q) / decoder.max_delta_rad, -1.0, 1.0)

    return policy


def pick_policy(
    spec: ArmSpec, builder: ObservationBuilder, decoder: ActionDecoder, let_go_at_m: float = 0.0
) -> Callable[[np.ndarray], np.ndarray]:
    """A scripted grasp from the observation alone: above the cube, down, close, lift to the
    goal. Steers on the commanded pose (``target_ee_pos``), as the env's IK test does. With
    ``let_go_at_m`` it opens the gripper once the tool is that high above the grasp (a drop)."""
    sl = {f.name: slice(f.start, f.stop) for f in builder.layout()}
    n = spec.n_joints
    state = {"phase": "above", "steps": 0, "grasp_z": 0.0}

    def toward(q_cmd: np.ndarray, p: np.ndarray) -> np.ndarray:
        q_goal = spec.inverse_kinematics(p)
        if q_goal is None:
            return np.zeros(n)
        return np.clip((q_goal - q_cmd) / decoder.max_delta_rad, -1.0, 1.0)

    def policy(obs: np.ndarray) -> np.ndarray:
        cube, goal = obs[sl["cube_pos"]], obs[sl["goal_pos"]]
        q_cmd = obs[sl["joint_target"]][:n]
        tool = obs[sl["target_ee_pos"]]
        a = np.zeros(decoder.n_actions)
        phase = state["phase"]
        state["steps"] += 1
        if obs[sl["prev_action"]][n] == 0.0 and state["steps"] > 1:  # a new episode began
            state.update(phase="above", steps=1)
            phase = "above"
        if phase == "above":
            above = cube + (0.0, 0.0, 0.05)
            a[:n], a[n] = toward(q_cmd, above), 1.0
            if np.linalg.norm(tool - above) < 0.004:
                state["phase"] = "down"
        elif phase == "down":
            a[:n], a[n] = toward(q_cmd, cube), 1.0
            if np.linalg.norm(tool - cube) < 0.003:
                state.update(phase="close", since=state["steps"], grasp_z=float(tool[2]))
        elif phase == "close":
            a[:n], a[n] = toward(q_cmd, cube), -1.0
            if state["steps"] - state["since"] >= 8:
                state["phase"] = "lift"
        else:
            a[:n], a[n] = toward(q_cmd, goal + (0.0, 0.0, 0.02)), -1.0
            if let_go_at_m and tool[2] - state["grasp_z"] > let_go_at_m:
                a[n] = 1.0
        return a

    return policy


def pid_alive(pid: int) -> bool:
    """A process that exists and is not a zombie (an orphan's reaper may be slow or absent)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    state = next((ln for ln in status.splitlines() if ln.startswith("State:")), "")
    return "Z" not in state.split()[1:2]


def kill_pid(pid: int | None) -> None:
    """SIGKILL a child a test started, if it is still there."""
    if pid is not None:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
