"""Deploy bench: a policy of any task in its env, on the ``sim`` backend and through the whole
mock chain, and the loop's timing while another process keeps the second core busy.

Per policy (a shipped name or a run dir), JSON lines:
* ``env_success_dr_{default,none}``: the env's own held-out success (Wilson interval);
* ``deploy_{sim,mock}_success`` and each task's figures (pick: grasped, lift, blind time);
* ``sim_vs_env_success`` and ``mock_vs_sim_success`` ratios (targets ≥ 0.9 each).
  Paired by default: the sim and mock backends replay the placements of the env's held-out
  episodes under DR ``none`` (``replayed.held_out_in_view`` → ``LoopConfig.placements``, as
  ``sim2real deploy --placements held-out`` does), so every ratio
  compares the same objects, and ``*_pairs`` count both / first only / second only / neither.
  For trace, held-out seams the rig cannot see are skipped (``env_success_dr_none_in_view``:
  the env on the episodes kept, the paired figure).
  (At p ≈ 0.3, two independent 100-episode samples cannot resolve a 0.9 ratio: σ ≈ 0.2.)
  ``--unpaired``: the loop draws its own placements, as ``sim2real deploy`` does;
* with ``--timing``: a mock run at the spec's own watchdog while a busy-loop process keeps a
  core busy: loop rate (target 20 Hz), period jitter p99 (target ≤ 5 ms), watchdog trips (0).
  The mock arm (emulator + physics) runs in its own process at ``--mock-nice``; the loop's
  thread at SCHED_FIFO unless ``--no-realtime``; ``--switch-interval`` sets the host's GIL
  switch interval. Each timing line names these settings (``variant``), to compare them.

    .venv/bin/python bench/deploy_mock.py pick-ppo trace-ppo --episodes 100
    .venv/bin/python bench/deploy_mock.py reach-ppo pick-ppo --timing --episodes 20 --backends ''
    .venv/bin/python bench/deploy_mock.py pick-ppo --timing --view --backends ''   # live view on
    .venv/bin/python bench/deploy_mock.py pick-ppo-pwm --spec hardware/specs/arm3_mg996r_pwm.yaml
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from support.load import busy_core, emit

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


def wilson(k: int, n: int) -> list[float]:
    from sim2real.evaluate.stats import wilson_interval

    lo, hi = wilson_interval(k, n)
    return [round(lo, 4), round(hi, 4)]


def breakdown(log_path: Path, nominal_s: float, over_ms: float = 5.0) -> dict[str, object]:
    """What made the long periods long. Period k (start k-1 to start k) is period k-1's work
    (read, perceive, infer, command, bookkeeping) when that passed the deadline, else the sleep
    plus period k's wake-up lateness. For the periods ``over_ms`` off: how many were each kind,
    and each section's mean and max in them."""
    import numpy as np

    log = np.load(log_path)
    period = log["period_s"].reshape(-1)
    late = log["wake_late_s"].reshape(-1)
    sections = ("read", "perceive", "infer", "command")
    work = {s: log[f"{s}_s"].reshape(-1) for s in sections}
    idx = [k for k in range(1, len(period)) if abs(period[k] - nominal_s) * 1e3 > over_ms]
    out: dict[str, object] = {"periods": int(np.isfinite(period).sum()), "long": len(idx)}
    if not idx:
        return out
    prev = np.array(idx) - 1
    total = sum(work[s][prev] for s in sections)
    out["overran"] = int((total > nominal_s).sum())  # the work itself passed the deadline
    out["woke_late"] = int((np.nan_to_num(late[idx]) * 1e3 > over_ms).sum())
    ms = {s: work[s][prev] * 1e3 for s in sections}
    ms["work"] = total * 1e3
    ms["wake_late"] = np.nan_to_num(late[idx]) * 1e3
    out["ms"] = {k: {"mean": round(float(v.mean()), 2), "max": round(float(v.max()), 2)}
                 for k, v in ms.items()}  # fmt: skip
    return out


def env_episodes(target: Any, dr: str, seeds: list[int]) -> tuple[dict[str, Any], list[bool]]:
    """``evaluate``'s figures on ``seeds`` and each episode's outcome, for the paired tables."""
    from sim2real.evaluate.core import report
    from sim2real.evaluate.rollout import run_episodes

    dr_config = target.dr(dr)
    t0 = time.perf_counter()
    result = run_episodes(target.policy, target.env_factory(dr_config), seeds)
    figures = report(target, dr_config, seeds, result, time.perf_counter() - t0)
    return figures, [e.success for e in result.episodes]


def live_view(ref: str, spec: Any, rrd: Path) -> Any:
    """``deploy --view save:FILE``'s live view of ``ref``'s task (the ``view`` extra)."""
    from sim2real.deploy.policy_io import policy_io
    from sim2real.export.policy import load_policy
    from sim2real.policies import resolve_policy
    from sim2real.view.live import LiveJob, LiveProcess

    objects = policy_io(spec, load_policy(resolve_policy(ref)).meta).contract.objects
    return LiveProcess(LiveJob(spec, objects, target="save", where=str(rrd), rate_hz=20.0)).start()


def dataset_figures(root: Path) -> dict[str, object]:
    """What the timing run's dataset holds, read back from its own files (``meta/info.json``)."""
    info = json.loads((root / "meta" / "info.json").read_text())
    return {"episodes": info.get("total_episodes"), "frames": info.get("total_frames"),
            "videos": sum(1 for _ in root.rglob("*.mp4"))}  # fmt: skip


def pairs(first: list[bool], second: list[bool]) -> dict[str, int]:
    both = sum(a and b for a, b in zip(first, second, strict=True))
    only1 = sum(a and not b for a, b in zip(first, second, strict=True))
    only2 = sum(b and not a for a, b in zip(first, second, strict=True))
    return {"both": both, "first_only": only1, "second_only": only2,
            "neither": len(first) - both - only1 - only2}  # fmt: skip


def main() -> None:
    import torch

    from hardware.spec import load_spec
    from sim2real.deploy.loop import LoopConfig
    from sim2real.deploy.replayed import held_out_in_view
    from sim2real.deploy.runner import DeployOptions, deploy
    from sim2real.evaluate import EvalTarget

    torch.set_num_threads(1)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policies", nargs="+", help="shipped names or run dirs")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--backends", default="sim,mock", help="comma list ('' for none)")
    parser.add_argument("--timing", action="store_true", help="add the busy-core timing run")
    parser.add_argument("--timing-episodes", type=int, default=20)
    parser.add_argument(
        "--unpaired", action="store_true",
        help="sim and mock draw the loop's own placements instead of the env's (DR none)",
    )  # fmt: skip
    parser.add_argument(
        "--watchdog-s", type=float, default=None,
        help="success runs only, on a machine shared with other jobs: a longer mock watchdog "
        "(the timing run always keeps the spec's)",
    )  # fmt: skip
    parser.add_argument(
        "--sim-clock", default="lockstep", choices=("lockstep", "realtime"),
        help="the sim backend's clock (realtime: physics runs on with the wall clock, so the "
        "figure depends on the machine's load)",
    )  # fmt: skip
    parser.add_argument(
        "--no-realtime",
        action="store_true",
        help="timing run: the loop's thread at normal priority",
    )
    parser.add_argument(
        "--mock-nice",
        type=int,
        default=None,
        help="timing run: the mock arm process's nice (default: DeployOptions')",
    )
    parser.add_argument(
        "--switch-interval",
        type=float,
        default=None,
        help="timing run: the host's sys.setswitchinterval in s (default 0.005)",
    )
    parser.add_argument(
        "--no-mock-realtime",
        action="store_true",
        help="timing run: the mock arm's process at normal priority (default: SCHED_FIFO)",
    )
    parser.add_argument(
        "--view",
        action="store_true",
        help="timing run: stream every period to a live Rerun view saved to a temporary file "
        "(deploy --view), to measure what the live view costs the loop",
    )
    parser.add_argument(
        "--dataset",
        action="store_true",
        help="timing run: record a LeRobot dataset with both cameras (deploy --record-dataset), "
        "to show the writer thread costs the loop no period and trips no watchdog",
    )
    parser.add_argument(
        "--mock-switch-interval",
        type=float,
        default=None,
        help="timing run: the mock arm process's GIL switch interval in s (default 0.005)",
    )
    parser.add_argument(
        "--spec",
        default=None,
        help="the arm's spec YAML (default: the shipped arm); a policy trained on the bare PWM "
        "build runs on hardware/specs/arm3_mg996r_pwm.yaml",
    )
    args = parser.parse_args()
    backends = [b for b in args.backends.split(",") if b]
    spec = load_spec(args.spec)
    machine = f"{platform.machine()} {os.cpu_count()} cpu"
    for ref in args.policies:
        env: dict[str, float] = {}
        outcomes: dict[str, list[bool]] = {}
        placements: tuple[Any, ...] = ()
        if len(backends) > 1:
            target = EvalTarget.load(ref)
            seeds = target.held_out_seeds(args.episodes)
            for dr in ("default", "none"):
                ev, outcomes[f"env_{dr}"] = env_episodes(target, dr, seeds)
                env[dr] = ev["success_rate"]
                emit(f"env_success_dr_{dr}", ev["success_rate"], "fraction", policy=ref,
                     ci95=ev["success_rate_wilson95"], episodes=args.episodes, machine=machine)  # fmt: skip
            if not args.unpaired:  # DR none's objects: the nominal model, as the sim backend runs
                kept, in_view = held_out_in_view(target, args.episodes)
                placements = tuple(in_view)
                if kept != seeds:  # trace: seams the rig cannot see are skipped; pair on the rest
                    ev, outcomes["env_none"] = env_episodes(target, "none", kept)
                    env["none"] = ev["success_rate"]
                    emit("env_success_dr_none_in_view", ev["success_rate"], "fraction",
                         policy=ref, ci95=ev["success_rate_wilson95"], episodes=args.episodes,
                         skipped=kept[-1] - seeds[0] + 1 - len(kept))  # fmt: skip
        rates = {}
        for backend in backends:
            t0 = time.perf_counter()
            # sim on the lockstep clock by default (one period of physics per command, as the
            # env steps): sim/env then measures the pipeline, not this machine's load
            clock = {"sim_clock": args.sim_clock} if backend == "sim" else {}  # sim's own
            opts = DeployOptions(backend=backend, watchdog_s=args.watchdog_s, **clock)
            try:
                res = deploy(ref, spec, opts,
                             LoopConfig(episodes=args.episodes, placements=placements))  # fmt: skip
            except Exception as exc:  # a stop is a result too: one line, then the next backend
                emit(f"deploy_{backend}_failed", str(exc).splitlines()[0], "", policy=ref,
                     wall_s=round(time.perf_counter() - t0, 1),
                     load_1min=round(os.getloadavg()[0], 2))  # fmt: skip
                continue
            s = res.summary().to_json()
            rates[backend] = s["success_rate"]
            outcomes[backend] = [e.success for e in res.episodes]
            emit(f"deploy_{backend}_success", s["success_rate"], "fraction", policy=ref,
                 task=s["task"], ci95=wilson(res.successes, s["episodes"]),
                 episodes=s["episodes"], wall_s=round(time.perf_counter() - t0, 1),
                 stopped_early=s["stopped_early"], watchdog_s=args.watchdog_s,
                 sim_clock=args.sim_clock if backend == "sim" else None,
                 placements="env (DR none)" if placements else "loop",
                 load_1min=round(os.getloadavg()[0], 2))  # fmt: skip
            emit(f"deploy_{backend}_task_figures", s["task_figures"], "", policy=ref,
                 episode_stops=len(s["episode_stops"]))  # fmt: skip
        paired = bool(placements)
        if "sim" in rates and env:
            ratio = rates["sim"] / env["default"] if env["default"] > 0 else float("nan")
            emit("sim_vs_env_success", round(ratio, 3), "ratio", policy=ref, target=0.9,
                 passed=ratio >= 0.9, against="env DR default")  # fmt: skip
            # the sim backend runs the nominal model, as DR `none` does: the like-for-like ratio
            like = rates["sim"] / env["none"] if env["none"] > 0 else float("nan")
            emit("sim_vs_env_none_success", round(like, 3), "ratio", policy=ref, target=0.9,
                 passed=like >= 0.9, paired=paired)  # fmt: skip
            if paired and len(outcomes["sim"]) == len(outcomes["env_none"]):
                emit("sim_vs_env_none_pairs", pairs(outcomes["env_none"], outcomes["sim"]), "",
                     policy=ref, first="env DR none", second="sim")  # fmt: skip
        if {"sim", "mock"} <= set(rates):
            ratio = rates["mock"] / rates["sim"] if rates["sim"] > 0 else float("nan")
            emit("mock_vs_sim_success", round(ratio, 3), "ratio", policy=ref, target=0.9,
                 passed=ratio >= 0.9, paired=paired)  # fmt: skip
            if len(outcomes["mock"]) == len(outcomes["sim"]):
                emit("mock_vs_sim_pairs", pairs(outcomes["sim"], outcomes["mock"]), "",
                     policy=ref, first="sim", second="mock")  # fmt: skip
        if args.timing:
            timing_opts = DeployOptions(backend="mock", realtime=not args.no_realtime)
            if args.mock_nice is not None:
                timing_opts = dataclasses.replace(timing_opts, mock_nice=args.mock_nice)
            timing_opts = dataclasses.replace(
                timing_opts,
                mock_switch_interval_s=args.mock_switch_interval,
                mock_realtime=not args.no_mock_realtime,
            )
            variant = {"realtime": timing_opts.realtime, "mock_nice": timing_opts.mock_nice,
                       "live_view": args.view, "dataset": args.dataset,
                       "mock_realtime": timing_opts.realtime and timing_opts.mock_realtime,
                       "switch_interval_s": args.switch_interval or sys.getswitchinterval(),
                       "mock_switch_interval_s": args.mock_switch_interval or 0.005}  # fmt: skip
            before = sys.getswitchinterval()
            if args.switch_interval is not None:
                sys.setswitchinterval(args.switch_interval)
            log_path = Path(tempfile.mkdtemp(prefix="deploy_timing_")) / "loop.npz"
            live = live_view(ref, spec, log_path.parent / "live.rrd") if args.view else None
            dataset = log_path.parent / "dataset" if args.dataset else None
            try:
                with busy_core():
                    res = deploy(ref, spec, timing_opts, LoopConfig(episodes=args.timing_episodes),
                                 log_path=log_path, live=live, dataset_path=dataset)  # fmt: skip
            except Exception as exc:  # a stop is a result too (a watchdog trip, a lost reply)
                emit("timing_busy_core_failed", str(exc).splitlines()[0], "", policy=ref,
                     variant=variant, load_1min=round(os.getloadavg()[0], 2))  # fmt: skip
                shutil.rmtree(log_path.parent, ignore_errors=True)
                continue
            finally:
                sys.setswitchinterval(before)
                if live is not None:
                    live.close()
                    emit("timing_busy_core_live_view", {"drawn": live.drawn,
                         "dropped": live.dropped, "frames_skipped": live.frames_skipped,
                         "failed": live.failed}, "periods", policy=ref, variant=variant)  # fmt: skip
            s = res.summary().to_json()
            jitter = s["period_jitter_ms"]
            emit("timing_busy_core_loop_hz", round(s["loop_hz"], 3), "Hz", policy=ref, target=20,
                 variant=variant, machine=machine, load_1min=round(os.getloadavg()[0], 2))  # fmt: skip
            emit("timing_busy_core_jitter_p99_ms", round(jitter["p99"], 3), "ms", policy=ref,
                 p50=round(jitter["p50"], 3), max=round(jitter["max"], 3), target=5.0,
                 passed=jitter["p99"] <= 5.0, variant=variant)  # fmt: skip
            emit("timing_busy_core_watchdog_trips", s["watchdog_trips"], "count", policy=ref,
                 target=0, overruns=s["overruns"], stopped_early=s["stopped_early"],
                 variant=variant)  # fmt: skip
            emit("timing_busy_core_sections_ms",
                 {k: {q: round(v, 3) for q, v in d.items()} for k, d in s["sections_ms"].items()},
                 "ms", policy=ref, success_rate=s["success_rate"], variant=variant)  # fmt: skip
            emit("timing_busy_core_wake_late_ms",
                 {q: round(v, 3) for q, v in s["wake_late_ms"].items()}, "ms", policy=ref,
                 variant=variant)  # fmt: skip
            emit("timing_busy_core_long_periods", breakdown(log_path, 1.0 / res.rate_hz), "",
                 policy=ref, variant=variant, load_1min=round(os.getloadavg()[0], 2))  # fmt: skip
            if dataset is not None:
                emit("timing_busy_core_dataset", dataset_figures(dataset), "", policy=ref,
                     episodes=args.timing_episodes, variant=variant)  # fmt: skip
            shutil.rmtree(log_path.parent, ignore_errors=True)


if __name__ == "__main__":
    main()
