"""Pick gap diagnosis: the same cube placements in the env and on the ``sim`` deploy backend.

For each held-out seed the env resets (its own cube placement) and runs the policy; the sim
backend (lockstep clock: deterministic, load-independent) then gets that same placement. Both
sides log what the policy saw (observation vectors) and what happened (grasped, max lift, a
drop by ``PickContract``'s rule, stop reason, success). Diagnostic switches (bench only, not
user options) turn single differences off on the deploy side, to price each one:

* ``--no-drop-stop``: the drop judgement never stops an episode (it is still counted);
* ``--env-start``: the deploy episode starts from the env's own start pose (home plus the
  env's random joint offsets) instead of the exact home pose;
* ``--clock realtime``: the sim backend's physics runs with the wall clock (at ``--rate 20``),
  as ``sim2real deploy --backend sim`` does by default, instead of one period per command.

``--loop-seed S`` instead runs the sim backend alone on the loop's own placements (drawn from
``LoopConfig(seed=S)``, as ``bench/deploy_mock.py`` draws them with the default seed), to tell
placement luck from the pipeline: ``pick_gap_sim_loop_placements``.

JSON lines: ``pick_gap_env_success``, ``pick_gap_sim_success``, the paired table
(``pick_gap_pairs``: both succeed / env only / sim only / neither), drop counts on both sides,
and the first step where the observations part (``pick_gap_obs_diff``: per field, the median
absolute difference over the first ``--compare-steps`` steps of paired episodes).

    .venv/bin/python bench/pick_gap.py pick-ppo --episodes 40
    .venv/bin/python bench/pick_gap.py pick-ppo --episodes 40 --no-drop-stop
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from support.load import emit

os.environ.setdefault("MUJOCO_GL", "egl")


def env_episodes(target: Any, dr: str, seeds: list[int], compare_steps: int) -> list[dict]:
    """The env's own episodes: placement, start pose, observations, grasp/lift/drop, success."""
    from sim2real.envs.pick import DROPPED_FROM_M

    env = target.env_factory(target.dr(dr))()
    u = env.unwrapped
    out = []
    try:
        for seed in seeds:
            obs, _ = env.reset(seed=seed)
            cube = u.task.cube_position(u).copy()
            quat = u.data.xquat[u.task._cube_body]
            yaw = 2.0 * math.atan2(float(quat[3]), float(quat[0]))
            rest_z, max_lift, drop_step = float(cube[2]), 0.0, -1
            grasped_ever = False
            obs_rows = [np.asarray(obs, dtype=float)]
            start_q = u.commanded_rad().copy()
            info: dict[str, Any] = {}
            for step in range(10_000):
                action = target.policy(np.asarray(obs)[None])[0]
                obs, _, term, trunc, info = env.step(action)
                if len(obs_rows) < compare_steps:
                    obs_rows.append(np.asarray(obs, dtype=float))
                grasped = u.task.is_grasped(u)
                grasped_ever |= grasped
                lift = float(u.task.cube_position(u)[2]) - rest_z
                max_lift = max(max_lift, lift)
                dropped = max_lift >= DROPPED_FROM_M and lift < 0.5 * DROPPED_FROM_M
                if drop_step < 0 and dropped and not grasped:
                    drop_step = step
                if term or trunc:
                    break
            out.append(
                {
                    "seed": seed,
                    "placement": np.array([cube[0], cube[1], yaw]),
                    "start_q": start_q,
                    "success": bool(info["is_success"]),
                    "grasped_ever": grasped_ever,
                    "max_lift_m": max_lift,
                    "drop_step": drop_step,
                    "obs": np.array(obs_rows),
                }
            )
    finally:
        env.close()
    return out


def sim_episodes(
    ref: str,
    env_eps: list[dict],
    rate_hz: float,
    drop_stop: bool,
    env_start: bool,
    clock: str = "lockstep",
) -> tuple[list[Any], dict[str, np.ndarray]]:
    """The same placements on the sim backend; (episode records, the log's rows)."""
    import sim2real.deploy.session as session_mod
    import sim2real.envs.pick as pick
    from hardware.spec import load_spec
    from sim2real.deploy.loop import LoopConfig
    from sim2real.deploy.policy_io import policy_io
    from sim2real.deploy.runner import DeployOptions, run_policy
    from sim2real.export.policy import load_policy
    from sim2real.policies import resolve_policy

    spec = load_spec()
    policy = load_policy(resolve_policy(ref))
    io = policy_io(spec, policy.meta)
    placements = [e["placement"] for e in env_eps]
    starts = [e["start_q"] for e in env_eps]
    episode = {"i": -1}

    def placement(self: Any, rng: np.random.Generator) -> dict[str, np.ndarray]:
        episode["i"] += 1
        return {"cube": placements[episode["i"]].copy()}

    def same_placement(self: Any, contract: Any, rng: np.random.Generator) -> dict[str, Any]:
        return contract.placement(rng)  # no redraw for the rig's sight: pairs stay paired

    patches: list[tuple[Any, str, Any]] = [
        (pick.PickContract, "placement", placement),
        (session_mod.ControlSession, "_placement", same_placement),
    ]
    if not drop_stop:
        patches.append((pick, "DROPPED_FROM_M", math.inf))
    if env_start:
        real_wait = session_mod.ControlSession._wait_until_ready

        def wait(self: Any, contract: Any, ep: int) -> Any:
            real_wait(self, contract, ep)  # objects seen and still, as always
            self.arm.move_to(starts[episode["i"]])
            return self.perception.perceive(self.arm.read_state(), 0.0)

        patches.append((session_mod.ControlSession, "_wait_until_ready", wait))
    saved = [(obj, name, getattr(obj, name)) for obj, name, _ in patches]
    for obj, name, value in patches:
        setattr(obj, name, value)
    log = Path(tempfile.mkdtemp(prefix="pick_gap_")) / "sim.npz"
    try:
        result = run_policy(
            lambda obs: policy(obs), io, spec, DeployOptions(backend="sim", sim_clock=clock),
            LoopConfig(episodes=len(placements), rate_hz=rate_hz), log_path=log,
        )  # fmt: skip
    finally:
        for obj, name, value in saved:
            setattr(obj, name, value)
    data = np.load(log)
    return result.episodes, {k: data[k] for k in data.files}


def loop_placements(ref: str, episodes: int, seed: int, rate_hz: float) -> None:
    """The sim backend (lockstep) alone, on the placements the deploy loop draws itself."""
    from hardware.spec import load_spec
    from sim2real.deploy.loop import LoopConfig
    from sim2real.deploy.policy_io import policy_io
    from sim2real.deploy.runner import DeployOptions, run_policy
    from sim2real.evaluate import wilson_interval
    from sim2real.export.policy import load_policy
    from sim2real.policies import resolve_policy

    spec = load_spec()
    policy = load_policy(resolve_policy(ref))
    result = run_policy(
        lambda obs: policy(obs), policy_io(spec, policy.meta), spec,
        DeployOptions(backend="sim", sim_clock="lockstep"),
        LoopConfig(episodes=episodes, rate_hz=rate_hz, seed=seed),
    )  # fmt: skip
    k = result.successes
    emit("pick_gap_sim_loop_placements", k / episodes, "fraction", episodes=episodes,
         loop_seed=seed, ci95=[round(v, 4) for v in wilson_interval(k, episodes)])  # fmt: skip


def main() -> None:
    import torch

    from sim2real.evaluate import EvalTarget

    torch.set_num_threads(1)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy", help="a shipped name or a run dir")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--seed-offset", type=int, default=0)
    parser.add_argument("--dr", default="none", help="the env's DR preset (the sim has none)")
    parser.add_argument("--rate", type=float, default=100.0,
                        help="the loop's rate (lockstep: one control period of physics per "
                        "command whatever the rate, and no waiting between them)")  # fmt: skip
    parser.add_argument("--no-drop-stop", action="store_true")
    parser.add_argument("--env-start", action="store_true")
    parser.add_argument("--clock", default="lockstep", choices=("lockstep", "realtime"))
    parser.add_argument("--compare-steps", type=int, default=5)
    parser.add_argument("--loop-seed", type=int, default=None)
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)
    if args.loop_seed is not None:
        loop_placements(args.policy, args.episodes, args.loop_seed, args.rate)
        return
    target = EvalTarget.load(args.policy)
    seeds = target.held_out_seeds(args.episodes, args.seed_offset)
    env_eps = env_episodes(target, args.dr, seeds, args.compare_steps)
    sim_eps, rows = sim_episodes(
        args.policy, env_eps, args.rate, not args.no_drop_stop, args.env_start, args.clock
    )
    variant = {"dr": args.dr, "drop_stop": not args.no_drop_stop, "env_start": args.env_start,
               "clock": args.clock, "rate_hz": args.rate}  # fmt: skip
    n = len(env_eps)
    env_ok = np.array([e["success"] for e in env_eps])
    sim_ok = np.array([e.success for e in sim_eps] + [False] * (n - len(sim_eps)))
    emit("pick_gap_env_success", float(env_ok.mean()), "fraction", episodes=n, **variant)
    emit("pick_gap_sim_success", float(sim_ok.mean()), "fraction", episodes=len(sim_eps),
         **variant)  # fmt: skip
    emit("pick_gap_pairs", {"both": int((env_ok & sim_ok).sum()),
                            "env_only": int((env_ok & ~sim_ok).sum()),
                            "sim_only": int((~env_ok & sim_ok).sum()),
                            "neither": int((~env_ok & ~sim_ok).sum())}, "episodes", **variant)  # fmt: skip
    sim_drops = [e.reason for e in sim_eps if e.reason and "dropped" in e.reason]
    env_drops = [e for e in env_eps if e["drop_step"] >= 0]
    emit("pick_gap_drops", {"sim_stopped": len(sim_drops), "env_dropped": len(env_drops),
                            "env_dropped_then_success": sum(e["success"] for e in env_drops)},
         "episodes", **variant)  # fmt: skip
    emit("pick_gap_grasped_ever", {
        "env": float(np.mean([e["grasped_ever"] for e in env_eps])),
        "sim": float(np.mean([e.figures["grasped_ever"] for e in sim_eps]))}, "fraction",
        **variant)  # fmt: skip
    emit("pick_gap_max_lift_m", {
        "env": float(np.mean([e["max_lift_m"] for e in env_eps])),
        "sim": float(np.mean([e.figures["max_lift_m"] for e in sim_eps]))}, "m", **variant)  # fmt: skip
    # the observations at the first steps of each paired episode, field by field
    from hardware.spec import load_spec
    from sim2real.deploy.policy_io import policy_io
    from sim2real.export.policy import load_policy
    from sim2real.policies import resolve_policy

    io = policy_io(load_spec(), load_policy(resolve_policy(args.policy)).meta)
    diffs: dict[str, list[float]] = {}
    ep_col, step_col = rows["episode"].ravel(), rows["step"].ravel()
    for i, e in enumerate(env_eps[: len(sim_eps)]):
        for k in range(min(args.compare_steps, len(e["obs"]))):
            hit = np.flatnonzero((ep_col == i) & (step_col == k))
            if not len(hit):
                continue
            o_sim, o_env = rows["obs"][hit[0]], e["obs"][k]
            for f in io.builder.layout():
                d = float(np.max(np.abs(o_sim[f.start : f.stop] - o_env[f.start : f.stop])))
                diffs.setdefault(f.name, []).append(d)
    emit("pick_gap_obs_diff", {k: round(float(np.nanmedian(v)), 5) for k, v in diffs.items()},
         "obs units", steps=args.compare_steps, **variant)  # fmt: skip
    per = [{"seed": e["seed"], "env": bool(e["success"]), "sim": bool(s.success),
            "env_lift": round(e["max_lift_m"], 3), "sim_lift": round(s.figures["max_lift_m"], 3),
            "env_drop": e["drop_step"], "sim_stop": s.reason} for e, s in zip(env_eps, sim_eps, strict=False)]  # fmt: skip
    emit("pick_gap_episodes", per, "", **variant)


if __name__ == "__main__":
    main()
