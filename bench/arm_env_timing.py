"""ArmEnv against the deploy loop: the same policy, the same backend, in one run.

A learner on the arm steps ``sim2real.finetune.ArmEnv``; the deploy loop runs the same chain by
itself. Both pace to the policy's rate, so the env should hold the loop's timing and success: this
bench runs a policy for N episodes through each, one after the other on fresh backends, and
prints JSON lines per path (``deploy_loop``, ``arm_env``): success rate, loop rate, period jitter
p50/p99, late periods, watchdog trips; then the env/loop ratios of p99 jitter and success. No
learner runs here: this is the baseline the fine-tuning loop's own timing is compared with.

    .venv/bin/python bench/arm_env_timing.py reach-ddpg --backend mock --episodes 5
    .venv/bin/python bench/arm_env_timing.py reach-ddpg --episodes 5 --watchdog-s 2  # loaded
    .venv/bin/python bench/arm_env_timing.py reach-ddpg --watchdog-s 2 --env-normal-priority
"""

from __future__ import annotations

import argparse
import os
import platform
import time

from support.load import emit_row

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


def emit(metric: str, value: object, unit: str = "", **extra: object) -> None:
    emit_row({"metric": metric, "value": value, "unit": unit, **extra})


def main() -> None:
    import numpy as np

    from hardware.spec import load_spec
    from sim2real.deploy.loop import LoopConfig
    from sim2real.deploy.policy_io import policy_io
    from sim2real.deploy.realtime import control_thread_priority
    from sim2real.deploy.runner import DeployOptions, run_policy
    from sim2real.export.policy import load_policy
    from sim2real.finetune.arm_env import ArmEnv
    from sim2real.policies import resolve_policy

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "policy", nargs="?", default="reach-ddpg",
        help="a shipped name or a run dir (a flat-observation policy)",
    )  # fmt: skip
    ap.add_argument("--backend", default="mock", choices=("sim", "mock"))
    ap.add_argument("--episodes", type=int, default=5)
    ap.add_argument("--seed", type=int, default=1_000_000)
    ap.add_argument(
        "--env-normal-priority",
        action="store_true",
        help="step the env at normal priority (the loop keeps its own): what that costs",
    )
    ap.add_argument(
        "--watchdog-s",
        type=float,
        default=None,
        help="mock/sim: a longer watchdog than the spec's, for a machine too loaded to hold it",
    )
    args = ap.parse_args()

    spec = load_spec()
    policy = load_policy(resolve_policy(args.policy))
    meta = policy.meta
    io = policy_io(spec, meta)
    opts = DeployOptions(backend=args.backend, watchdog_s=args.watchdog_s)
    common = {"policy": args.policy, "backend": args.backend, "episodes": args.episodes,
              "watchdog_s": args.watchdog_s or spec.safety.watchdog_timeout_s,
              "env_priority": "normal" if args.env_normal_priority else "loop's",
              "machine": f"{platform.machine()} {os.cpu_count()} cpu",
              "date": time.strftime("%Y-%m-%d")}  # fmt: skip

    def through_loop() -> dict[str, float]:
        t0 = time.monotonic()
        result = run_policy(
            lambda obs: policy(obs), io, spec, opts,
            LoopConfig(rate_hz=meta.control_hz, episodes=args.episodes, seed=args.seed),
        )  # fmt: skip
        s = result.summary().to_json()
        if result.stopped_early:
            raise RuntimeError(result.stopped_early)
        return {
            "success": s["success_rate"],
            "loop_hz": s["loop_hz"],
            "p50_jitter_ms": s["period_jitter_ms"]["p50"],
            "p99_jitter_ms": s["period_jitter_ms"]["p99"],
            "late_periods": s["overruns"],
            "watchdog_trips": s["watchdog_trips"],
            "wall_s": time.monotonic() - t0,
        }

    def through_env() -> dict[str, float]:
        t0 = time.monotonic()
        env = ArmEnv.for_policy(args.policy, spec, opts)
        successes = []
        try:
            # the stepping thread at the deploy loop's priority, as run_policy runs the loop
            with control_thread_priority(opts.realtime and not args.env_normal_priority):
                for episode in range(args.episodes):
                    obs, _ = env.reset(seed=args.seed + episode)
                    truncated = False
                    while not truncated:
                        obs, _, _, truncated, info = env.step(policy(obs))
                    successes.append(bool(info["is_success"]))
            periods = np.asarray(env.periods_s)
            jitter = np.abs(periods - env.period_s)
            return {
                "success": float(np.mean(successes)),
                "loop_hz": float(1.0 / periods.mean()),
                "p50_jitter_ms": float(np.percentile(jitter, 50) * 1e3),
                "p99_jitter_ms": float(np.percentile(jitter, 99) * 1e3),
                "late_periods": env.overruns,
                "watchdog_trips": sum("watchdog" in e for e in env.estops),
                "wall_s": time.monotonic() - t0,
            }
        finally:
            env.close()

    figures: dict[str, dict[str, float]] = {}
    for name, run in (("deploy_loop", through_loop), ("arm_env", through_env)):
        try:
            figures[name] = run()
        except Exception as exc:  # a loaded machine can trip the spec's watchdog: say so
            emit(f"{name}_stopped", (str(exc).splitlines() or [type(exc).__name__])[0], **common)
            continue
        for key, value in figures[name].items():
            emit(f"{name}_{key}", value, **common)
    if len(figures) == 2:
        loop, arm = figures["deploy_loop"], figures["arm_env"]
        emit("env_vs_loop_p99_jitter", arm["p99_jitter_ms"] / max(loop["p99_jitter_ms"], 1e-9),
             "ratio", **common)  # fmt: skip
        emit("env_vs_loop_success", arm["success"] / max(loop["success"], 1e-9), "ratio", **common)


if __name__ == "__main__":
    main()
