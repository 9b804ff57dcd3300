"""The control session's public steps, driven by hand on SimArm (lockstep physics): what a
driver (the deploy loop, ArmEnv, a script) can rely on."""

from __future__ import annotations

import ast
import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hardware.safety import SafetyFilter
from hardware.spec import ArmSpec
from sim2real.deploy.policy_io import PolicyIO
from sim2real.deploy.runner import BACKENDS, DeployOptions
from sim2real.deploy.session import LOG_KEYS, ControlSession, LoopConfig, LoopLog
from sim2real.envs.contract import View
from sim2real.errors import ConfigError

from .conftest import ik_policy  # type: ignore[import-not-found]

DEPLOY = Path(__file__).parents[3] / "sim2real" / "deploy"


@contextlib.contextmanager
def _session(spec: ArmSpec, io: PolicyIO, config: LoopConfig) -> Iterator[ControlSession]:
    with contextlib.ExitStack() as stack:
        opts = DeployOptions(backend="sim", sim_clock="lockstep")
        arm, perception, world = BACKENDS["sim"](spec, io, opts, stack)
        session = ControlSession(arm, perception, world, io, config, LoopLog())
        stack.callback(session.close)
        yield session


def test_a_command_is_judged_on_the_view_at_the_start_of_the_next_period(
    spec: ArmSpec, reach_io: PolicyIO, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Period k's command is scored (as step k) on the view the next ``sense`` takes; the
    last one by ``judge_last``, a period later. The safety filter runs once per ``act``."""
    filtered = {"n": 0}
    real_filter = SafetyFilter.filter

    def counting(self: SafetyFilter, *a: Any, **k: Any) -> np.ndarray:
        filtered["n"] += 1
        return real_filter(self, *a, **k)

    policy = ik_policy(spec, reach_io.builder, reach_io.decoder)
    with _session(spec, reach_io, LoopConfig(episode_steps=4)) as session:
        session.begin_episode(0, np.random.default_rng(0))
        contract = session.contract
        assert contract is not None
        scored: list[tuple[int, np.ndarray | None]] = []
        real_score = contract.score

        def score(view: View, step: int) -> str | None:
            scored.append((step, view.commanded_rad))
            return real_score(view, step)

        contract.score = score  # type: ignore[method-assign]
        monkeypatch.setattr(SafetyFilter, "filter", counting)
        sent = []
        for k in range(session.steps):
            sensed = session.sense()
            assert [s for s, _ in scored] == list(range(k))  # the commands before this one
            obs = session.observe(sensed)
            sent.append(session.act(np.asarray(policy(obs), dtype=float), sensed, obs))
            session.pace()
        assert filtered["n"] == session.steps
        session.judge_last()
        assert [s for s, _ in scored] == [0, 1, 2, 3]
        for (_, commanded), out in zip(scored, sent, strict=True):
            np.testing.assert_array_equal(commanded, out)
        record = session.end_episode()
        assert record.reason is None and np.isfinite(record.distance_m)
        session.park()
        assert not session.arm.is_enabled
    rows = session.log.rows if session.log is not None else {}
    assert set(LOG_KEYS) <= set(rows) and rows["step"] == [0, 1, 2, 3]
    assert len(session.clock.periods_s) == session.steps - 1  # start to start, after the first


def test_a_blind_period_holds_still_and_keeps_the_gripper(spec: ArmSpec, pick_io: PolicyIO) -> None:
    with _session(spec, pick_io, LoopConfig(episode_steps=2)) as session:
        session.begin_episode(0, np.random.default_rng(0))
        session.prev_action = np.array([0.5, -0.5, 0.2, 1.0])
        obs, action = session.blind_period()
        assert np.all(np.isnan(obs)) and obs.shape == (pick_io.builder.size,)
        np.testing.assert_array_equal(action, [0.0, 0.0, 0.0, 1.0])
        assert session.blind_periods == 1
        session.begin_episode(1, np.random.default_rng(1))
        assert session.blind_periods == 0  # counted per episode


def test_a_dry_run_filters_every_command_and_sends_none(spec: ArmSpec, reach_io: PolicyIO) -> None:
    with _session(spec, reach_io, LoopConfig(episode_steps=3, dry_run=True)) as session:
        session.begin_episode(0, np.random.default_rng(0))
        received = len(session.arm.received_targets_rad())  # type: ignore[attr-defined]
        filtered = session.arm.safety.stats.commands
        sensed = session.sense()
        out = session.act(np.ones(reach_io.decoder.n_actions), sensed, session.observe(sensed))
        assert session.arm.safety.stats.commands == filtered + 1  # judged by the filter
        assert len(session.arm.received_targets_rad()) == received  # type: ignore[attr-defined]
        assert out.shape == (spec.n_actuators,) and session.log is not None
        np.testing.assert_array_equal(session.log.rows["sent_rad"][-1], out)  # and logged


def test_the_period_steps_need_an_episode(spec: ArmSpec, reach_io: PolicyIO) -> None:
    with (
        _session(spec, reach_io, LoopConfig()) as session,
        pytest.raises(ConfigError, match="no episode in flight"),
    ):
        session.sense()


def test_objects_the_arm_hides_are_looked_for_from_park_without_waiting_half_the_timeout(
    spec: ArmSpec, reach_io: PolicyIO, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A world that placed the objects knows they are there: unseen for ``LOOK_FROM_PARK_S``
    (at home the arm may hide one), the arm parks, and homes again once they are seen; it does
    not wait out half of a start timeout sized for a slow machine. The perception here sees the
    target only from park."""
    from sim2real.envs.contract import Percept

    monkeypatch.setattr(ControlSession, "LOOK_FROM_PARK_S", 0.2)
    timeout_s = 60.0  # half of it is far beyond any stall a loaded machine makes
    with _session(spec, reach_io, LoopConfig(episode_steps=2, start_timeout_s=timeout_s)) as s:
        parked_at: list[float] = []
        real_park, real_perceive = s.arm.park, s.perception.perceive

        def park() -> Any:  # the lockstep simulator's time: the wait does not sleep
            parked_at.append(s.arm.now_s())
            return real_park()

        def perceive(state: Any, command_s: float) -> Percept:
            seen = real_perceive(state, command_s)
            return seen if parked_at else Percept(seen.tool_m, {})  # hidden until parked

        monkeypatch.setattr(s.arm, "park", park)
        monkeypatch.setattr(s.perception, "perceive", perceive)
        start = s.arm.now_s()
        s.begin_episode(0, np.random.default_rng(0))
        assert len(parked_at) == 1 and parked_at[0] - start < 0.5 * timeout_s
        home = spec.actuator_home_rad  # home again before the episode's first period
        np.testing.assert_allclose(s.arm.read_state().positions_rad, home, atol=0.05)
        assert s.contract is not None and s.step == 0


def _functions(path: Path) -> Iterator[tuple[str, int]]:
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            assert node.end_lineno is not None
            yield node.name, node.end_lineno - node.lineno + 1


@pytest.mark.parametrize(
    "module",
    [
        "session.py", "loop.py", "clock.py", "runner.py", "connection.py", "child.py",
        "mock_arm.py", "render_process.py", "perception_process.py",
    ],
)  # fmt: skip
def test_no_function_in_the_control_runtime_is_longer_than_60_lines(module: str) -> None:
    long = {name: n for name, n in _functions(DEPLOY / module) if n > 60}
    assert not long, f"{module}: {long}"


def test_no_module_reaches_into_the_sessions_private_members() -> None:
    """Drivers use the session's public steps only; private names stay in their module."""
    root = DEPLOY.parent
    offenders = []
    for path in root.rglob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                "sim2real.deploy"
            ):
                offenders += [f"{path.name}: {a.name}" for a in node.names
                              if a.name.startswith("_") and not a.name.startswith("__")]  # fmt: skip
            if (
                isinstance(node, ast.Attribute)
                and node.attr.startswith("_")
                and not node.attr.startswith("__")
                and isinstance(node.value, ast.Attribute)
                and node.value.attr in {"session", "loop"}
            ):
                offenders.append(f"{path.name}: .{node.value.attr}.{node.attr}")
    assert not offenders, offenders


def test_an_object_or_tool_unseen_past_the_blind_limit_stops_the_episode(
    spec: ArmSpec, pick_io: PolicyIO
) -> None:
    """The limit counts each object's blind time (a lost track from its loss) and the tool's,
    from the episode's start at most; past it, one line naming what is unseen."""
    from sim2real.deploy.session import DeployStopError
    from sim2real.envs.contract import ObjectEstimate, Percept

    with _session(spec, pick_io, LoopConfig(episode_steps=2, blind_limit_s=2.0)) as session:
        session.begin_episode(0, np.random.default_rng(0))
        contract = session.contract
        assert contract is not None
        t0 = session._begun_s
        cube = ObjectEstimate(np.array([0.15, 0.0, 0.0125]), blind_s=2.5)
        tool = np.array([0.15, 0.0, 0.1])
        # early in the episode a long blind time is the wait before it: not held against it
        session.check_blind(contract, Percept(tool, {"cube": cube}), t0 + 1.0)
        with pytest.raises(DeployStopError, match=r"^blind: cube unseen by the cameras for 2\.5 "
                           r"s mid-episode \(limit 2\.0 s\); held, then parked$"):  # fmt: skip
            session.check_blind(contract, Percept(tool, {"cube": cube}), t0 + 3.0)
        seen = ObjectEstimate(cube.position_m, blind_s=0.0)
        with pytest.raises(DeployStopError, match=r"^blind: tool unseen .* for 2\.1 s"):
            session.check_blind(contract, Percept(tool, {"cube": seen}, 2.1), t0 + 3.0)
        # a track lost mid-episode counts from its loss
        session.check_blind(contract, Percept(tool, {}), t0 + 3.0)
        session.check_blind(contract, Percept(tool, {}), t0 + 4.9)
        with pytest.raises(DeployStopError, match=r"^blind: cube unseen .* for 2\.1 s"):
            session.check_blind(contract, Percept(tool, {}), t0 + 5.1)


def test_a_cube_carried_in_the_fingers_is_not_held_against_the_blind_limit(
    spec: ArmSpec, pick_io: PolicyIO
) -> None:
    """Hidden in fingers that hold it, the cube is where the carry rule puts it (the tool): the
    limit counts it again once the fingers let go."""
    from sim2real.deploy.session import DeployStopError
    from sim2real.envs.contract import ObjectEstimate, Percept

    with _session(spec, pick_io, LoopConfig(episode_steps=2, blind_limit_s=2.0)) as session:
        session.begin_episode(0, np.random.default_rng(0))
        contract = session.contract
        assert contract is not None and spec.gripper is not None
        t0 = session._begun_s
        tool = np.array([0.15, 0.0, 0.05])
        n = spec.n_joints
        commanded = np.append(spec.actuator_home_rad[:n], spec.gripper.closed_rad)
        span = spec.gripper.open_rad - spec.gripper.closed_rad
        blocked = commanded.copy()  # the fingers stopped half open: they hold something
        blocked[n] = spec.gripper.closed_rad + 0.5 * span
        contract.observe_arm(blocked, commanded)
        at_tool = ObjectEstimate(tool.copy(), blind_s=0.0)
        contract.readings(Percept(tool, {"cube": at_tool}), 0)
        assert contract.expected_hidden() == frozenset({"cube"})
        hidden = ObjectEstimate(tool.copy(), blind_s=2.5)
        session.check_blind(contract, Percept(tool, {"cube": hidden}), t0 + 3.0)  # carried
        contract.observe_arm(commanded, commanded)  # the fingers shut: the cube is gone
        contract.readings(Percept(tool, {"cube": hidden}), 1)
        assert contract.expected_hidden() == frozenset()
        with pytest.raises(DeployStopError, match=r"^blind: cube unseen"):
            session.check_blind(contract, Percept(tool, {"cube": hidden}), t0 + 3.0)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_a_blind_limit_that_is_not_a_time_is_refused_naming_it(bad: float) -> None:
    with pytest.raises(ConfigError, match=rf"blind_limit_s {bad} must be > 0"):
        LoopConfig(blind_limit_s=bad)
