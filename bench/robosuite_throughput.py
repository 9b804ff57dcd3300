"""robosuite backend throughput: raw robosuite and our wrapper in the same run, plus each speed knob.

Prints one JSON line per figure. Rates are steps per CPU second of this process (``wall``: steps
per wall-clock second), because other jobs share the two cores and CPU time is what they cannot
change. Every configuration is built once, then stepped one episode at a time, round-robin over all
configurations for ``BENCH_ROUNDS`` rounds, so load drifts hit every figure alike: compare ratios.
Episodes take random actions and include their reset (robosuite's default reset recompiles the
XML).

- ``robosuite_lift_default``: ``robosuite.make("Lift", robots="Panda")`` with its defaults
  (``hard_reset=True``, all observables, its viewer object), without camera observations; then
  with ``hard_reset=False``; then also with every observable disabled (one knob at a time).
- ``robosuite_lift_raw`` / ``_ours``: ``Sim2Real/RobosuiteLift-v0`` (``dr=default``) runs an
  episode, then the robosuite env inside it (``hard_reset=False``, observables off, no viewer)
  replays exactly that episode without the wrapper (same RNG state at reset, same actions, same
  randomised model): the wrapper overhead (target ≤ 10%), and the wrapper's share of each episode.
- knobs: controller, control frequency, pixels at 84 and 48; and the native pick for the
  "≥ 50× robosuite Lift" figure of the sim-core issue (robosuite Lift as env_throughput.py has it).

Run: ``MUJOCO_GL=egl nice -n 10 .venv/bin/python bench/robosuite_throughput.py`` (BENCH_ROUNDS).
"""

from __future__ import annotations

import os
import platform
import time
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import gymnasium as gym
import mujoco
import numpy as np
from support.load import emit_row

import sim2real.envs  # noqa: F401  (registers the ids)

ROUNDS = int(os.environ.get("BENCH_ROUNDS", "6"))
LIFT, REACH = "Sim2Real/RobosuiteLift-v0", "Sim2Real/RobosuiteReach-v0"


def _actions(n: int, low: np.ndarray, high: np.ndarray, seed: int) -> np.ndarray:
    u = np.random.default_rng(seed).uniform(-1.0, 1.0, (n, len(low)))
    return u * (high - low) / 2 + (high + low) / 2


class Case:
    """One configuration; ``episode()`` runs one timed episode (reset included)."""

    steps = 0
    seconds = 0.0
    cpu_seconds = 0.0

    def episode(self) -> float:
        raise NotImplementedError

    def timed(self) -> tuple[float, float]:
        """(wall s, CPU s of this process) for one episode. CPU time ignores other processes'
        load, which is what the raw-vs-ours overhead needs on a shared machine."""
        c0, t0 = time.process_time(), time.perf_counter()
        n = self.episode()
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        self.steps, self.seconds = self.steps + int(n), self.seconds + dt
        self.cpu_seconds += dc
        return dt, dc

    @property
    def rate(self) -> float:
        """Steps per CPU second of this process: what other processes' load cannot change
        (llvmpipe's render threads count too, so pixel cases show their full CPU cost)."""
        return self.steps / self.cpu_seconds

    @property
    def wall_rate(self) -> float:
        return self.steps / self.seconds

    def close(self) -> None:
        pass


class GymCase(Case):
    """Our wrapper (or any registered id): env.reset, then steps until truncation."""

    def __init__(self, env_id: str, episodes_per_call: int = 1, **kw: Any) -> None:
        self.env = gym.make(env_id, **kw)
        self.n = self.base.max_episode_steps * episodes_per_call
        space: Any = self.env.action_space
        self.actions = _actions(self.n, space.low, space.high, 0).astype(np.float32)
        self.k = 0
        rs = getattr(self.base, "robosuite_env", None)
        self.recorder = Recorder(rs) if rs is not None else None

    @property
    def base(self) -> Any:
        return self.env.unwrapped

    def episode(self) -> float:
        self.env.reset(seed=self.k)
        self.k += 1
        last = len(self.actions) - 1
        for i, a in enumerate(self.actions):
            *_, term, trunc, _ = self.env.step(a)
            if (term or trunc) and i < last:  # the next call's reset starts the next episode
                self.env.reset()
        return self.n

    def close(self) -> None:
        self.env.close()


class Recorder:
    """Shadows robosuite's ``step``/``reset`` on one env instance: times them (the wrapper's share
    is the rest of each wrapped episode) and records what the wrapper sent, so ``replay`` can run
    the very same episode raw: same RNG state at reset, same actions, same randomised model."""

    def __init__(self, rs: Any) -> None:
        self.rs, self.inner_s = rs, 0.0
        self.model, self.data = rs.sim.model._model, rs.sim.data._data
        self._spec = mujoco.mjtState.mjSTATE_INTEGRATION
        self.state0 = self._get_state()
        self._step, self._reset = rs.step, rs.reset
        self.rng_state: dict[str, Any] = {}
        self.actions: list[np.ndarray] = []
        rs.step, rs.reset = self._timed_step, self._timed_reset

    def _timed_step(self, action: np.ndarray) -> Any:
        if not self.actions:  # the state the wrapper's reset left (object offset included)
            self.state0 = self._get_state()
        self.actions.append(np.array(action))
        t0 = time.perf_counter()
        out = self._step(action)
        self.inner_s += time.perf_counter() - t0
        return out

    def _timed_reset(self) -> Any:
        self.rng_state, self.actions = self.rs.rng.bit_generator.state, []
        t0 = time.perf_counter()
        out = self._reset()
        self.inner_s += time.perf_counter() - t0
        return out

    def _get_state(self) -> np.ndarray:
        state = np.empty(mujoco.mj_stateSize(self.model, self._spec))
        mujoco.mj_getState(self.model, self.data, state, self._spec)
        return state

    def replay(self) -> tuple[float, float, int]:
        """(wall s, CPU s, steps) of the last wrapped episode replayed on raw robosuite."""
        actions = list(self.actions)
        c0, t0 = time.process_time(), time.perf_counter()
        self.rs.rng.bit_generator.state = self.rng_state
        self._reset()
        mujoco.mj_setState(self.model, self.data, self.state0, self._spec)
        for a in actions:
            self._step(a)
        return time.perf_counter() - t0, time.process_time() - c0, len(actions)


class RawCase(Case):
    """The robosuite env inside a GymCase, replaying that case's last episode without the
    wrapper: identical settings and physics, so the pair differs only by our code."""

    def __init__(self, ours: GymCase) -> None:
        self.ours = ours

    def episode(self) -> float:
        raise RuntimeError("RawCase runs through replay()")

    def replay(self) -> tuple[float, float]:
        recorder = self.ours.recorder
        assert recorder is not None, "replay needs a robosuite env"
        dt, dc, n = recorder.replay()
        self.steps, self.seconds = self.steps + n, self.seconds + dt
        self.cpu_seconds += dc
        return dt, dc


class RobosuiteCase(Case):
    """``robosuite.make("Lift", robots="Panda")``, its defaults but no camera obs, + overrides."""

    def __init__(self, n: int, observables: bool = True, **overrides: Any) -> None:
        from sim2real.randomization.robosuite_compat import import_robosuite

        self.rs = import_robosuite().make(
            "Lift",
            robots="Panda",
            has_renderer=False,
            has_offscreen_renderer=False,
            use_camera_obs=False,
            seed=0,  # every variant starts the same episodes: differences are the knob's
            **overrides,
        )
        if not observables:
            for name in sorted(self.rs.observation_names):
                self.rs.modify_observable(name, "enabled", False)
        low, high = self.rs.action_spec
        self.n, self.actions = n, _actions(n, low, high, 0)

    def episode(self) -> float:
        self.rs.reset()
        for a in self.actions:
            self.rs.step(a)
        return self.n

    def close(self) -> None:
        self.rs.close()


def emit(metric: str, value: float, unit: str, **extra: object) -> None:
    emit_row({"metric": metric, "value": round(value, 3), "unit": unit, **extra})


def main() -> None:
    import torch

    torch.set_num_threads(1)
    lift_ours = GymCase(LIFT, dr="default")
    lift_none = GymCase(LIFT, dr="none")
    reach_ours = GymCase(REACH, dr="default")
    cases: dict[str, Case] = {
        "default": RobosuiteCase(100),
        "hard_reset_off": RobosuiteCase(100, hard_reset=False),
        "observables_off": RobosuiteCase(100, observables=False, hard_reset=False),
        "lift_raw": RawCase(lift_ours),
        "lift_ours": lift_ours,
        "lift_raw_none": RawCase(lift_none),
        "lift_ours_none": lift_none,
        "reach_raw": RawCase(reach_ours),
        "reach_ours": reach_ours,
        "OSC_POSITION": GymCase(LIFT, controller="OSC_POSITION"),
        "JOINT_POSITION": GymCase(LIFT, controller="JOINT_POSITION"),
        "JOINT_TORQUE": GymCase(LIFT, controller="JOINT_TORQUE"),
        "10hz": GymCase(LIFT, control_hz=10.0, max_episode_steps=50),
        "40hz": GymCase(LIFT, control_hz=40.0, max_episode_steps=200),
        "pixels84": GymCase(LIFT, obs_mode="pixels", image_size=84),
        "pixels48": GymCase(LIFT, obs_mode="pixels", image_size=48),
        "arm3pick": GymCase("Sim2Real/Arm3Pick-v0", episodes_per_call=40, dr="default"),
    }
    load_before = os.getloadavg()[0]
    pairs = (
        ("lift", "lift_raw", "lift_ours"),
        ("lift_none", "lift_raw_none", "lift_ours_none"),
        ("reach", "reach_raw", "reach_ours"),
    )
    cpu_ratios: dict[str, list[float]] = {key: [] for key, _, _ in pairs}
    wall_ratios: dict[str, list[float]] = {key: [] for key, _, _ in pairs}
    for _ in range(ROUNDS):
        for case in cases.values():
            if not isinstance(case, RawCase):
                case.timed()
        # A wrapped episode, then the same episode replayed raw: three pairs per round.
        for key, raw, ours in pairs:
            raw_case = cases[raw]
            assert isinstance(raw_case, RawCase)
            for _ in range(3):
                w_ours, c_ours = cases[ours].timed()
                w_raw, c_raw = raw_case.replay()
                cpu_ratios[key].append(c_raw / c_ours)
                wall_ratios[key].append(w_raw / w_ours)
    # Wrapper share: the time of the wrapped episodes spent outside robosuite's step/reset.
    share: dict[str, float] = {}
    for key in ("lift_ours", "reach_ours"):
        case = cases[key]
        assert isinstance(case, GymCase) and case.recorder is not None
        share[key] = 1.0 - case.recorder.inner_s / case.seconds
    rate = {k: c.rate for k, c in cases.items()}
    wall = {k: round(c.wall_rate, 2) for k, c in cases.items()}
    for c in cases.values():
        c.close()

    emit(
        "robosuite_lift_default_steps_per_cpu_s",
        rate["default"],
        "steps/cpu-s",
        wall=wall["default"],
        settings="robosuite defaults (hard_reset=True, observables on), no camera obs",
        machine=f"{platform.machine()} {os.cpu_count()} cpu",
        python=platform.python_version(),
        load_1min=[round(load_before, 2), round(os.getloadavg()[0], 2)],
        rounds=ROUNDS,
    )
    emit(
        "robosuite_lift_hard_reset_off_steps_per_cpu_s",
        rate["hard_reset_off"],
        "steps/cpu-s",
        wall=wall["hard_reset_off"],
        vs_default=round(rate["hard_reset_off"] / rate["default"], 3),
    )
    emit(
        "robosuite_lift_observables_off_steps_per_cpu_s",
        rate["observables_off"],
        "steps/cpu-s",
        wall=wall["observables_off"],
        settings="robosuite defaults + hard_reset=False + every observable disabled",
        vs_hard_reset_off=round(rate["observables_off"] / rate["hard_reset_off"], 3),
    )
    emit(
        "robosuite_lift_raw_steps_per_cpu_s",
        rate["lift_raw"],
        "steps/cpu-s",
        wall=wall["lift_raw"],
        settings="the robosuite env our wrapper builds, stepped directly",
    )
    emit(
        "robosuite_lift_ours_steps_per_cpu_s",
        rate["lift_ours"],
        "steps/cpu-s",
        wall=wall["lift_ours"],
        dr="default",
        vs_default=round(rate["lift_ours"] / rate["default"], 3),
    )
    for key, name, dr in (
        ("lift", "robosuite_lift_wrapper_overhead", "default"),
        ("lift_none", "robosuite_lift_wrapper_overhead_dr_none", "none"),
        ("reach", "robosuite_reach_wrapper_overhead", "default"),
    ):
        overhead = 1.0 - float(np.median(cpu_ratios[key]))
        wall_over = 1.0 - float(np.median(wall_ratios[key]))
        emit(
            name,
            overhead,
            "fraction",
            dr=dr,
            target=0.10,
            passed=overhead <= 0.10,
            wall_clock=round(wall_over, 3),
            pairs=len(cpu_ratios[key]),
            method="median over episodes of raw/ours CPU time, raw replaying the same episode",
        )
    for key, name in (("lift_ours", "robosuite_lift"), ("reach_ours", "robosuite_reach")):
        emit(
            f"{name}_wrapper_share",
            share[key],
            "fraction",
            dr="default",
            target=0.10,
            passed=share[key] <= 0.10,
            method="time outside robosuite's step/reset in the wrapped episodes",
        )
    emit(
        "robosuite_reach_ours_steps_per_cpu_s",
        rate["reach_ours"],
        "steps/cpu-s",
        wall=wall["reach_ours"],
        dr="default",
        raw=round(rate["reach_raw"], 3),
    )
    base = rate["lift_ours"]
    emit(
        "robosuite_lift_osc_pose_steps_per_cpu_s",
        base,
        "steps/cpu-s",
        wall=wall["lift_ours"],
        control_hz=20,
        sim_s_per_cpu_s=round(base / 20, 3),
    )
    for ctrl in ("OSC_POSITION", "JOINT_POSITION", "JOINT_TORQUE"):
        emit(
            f"robosuite_lift_{ctrl.lower()}_steps_per_cpu_s",
            rate[ctrl],
            "steps/cpu-s",
            wall=wall[ctrl],
            vs_osc_pose=round(rate[ctrl] / base, 3),
        )
    for hz in (10, 40):
        r = rate[f"{hz}hz"]
        emit(
            f"robosuite_lift_{hz}hz_steps_per_cpu_s",
            r,
            "steps/cpu-s",
            wall=wall[f"{hz}hz"],
            control_hz=hz,
            sim_s_per_cpu_s=round(r / hz, 3),
            vs_20hz=round(r / base, 3),
        )
    for size in (84, 48):
        r = rate[f"pixels{size}"]
        emit(
            f"robosuite_lift_pixels{size}_steps_per_cpu_s",
            r,
            "steps/cpu-s",
            wall=wall[f"pixels{size}"],
            camera="agentview",
            dr="default",
            vs_state=round(r / base, 3),
        )
    emit(
        "arm3pick_steps_per_cpu_s",
        rate["arm3pick"],
        "steps/cpu-s",
        wall=wall["arm3pick"],
        dr="default",
    )
    ratio = rate["arm3pick"] / rate["hard_reset_off"]
    emit(
        "arm3pick_vs_robosuite_lift",
        ratio,
        "ratio",
        target=50,
        passed=ratio >= 50,
        reference="robosuite_lift_hard_reset_off (as bench/env_throughput.py)",
    )


if __name__ == "__main__":
    main()
