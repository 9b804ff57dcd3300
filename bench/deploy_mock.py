"""Deploy bench: one reach policy in simulation and through the whole mock chain.

Figures (JSON lines): env success (held-out seeds, DR none and default), deploy success on the
``sim`` backend (SimArm, ground-truth perception) and on the ``mock`` backend (emulator on a pty +
two rendered 640x480 cameras → ArUco → triangulation → Kalman), their ratio (target ≥ 0.9),
the achieved loop rate, period jitter p50/p99 (target p99 ≤ 5 ms at 20 Hz) and per-section
timings. Usage: python bench/deploy_mock.py [RUN_DIR] [--episodes N]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


def emit(metric: str, value: object, unit: str = "", **extra: object) -> None:
    print(json.dumps({"metric": metric, "value": value, "unit": unit, **extra}), flush=True)


def main() -> None:
    import numpy as np
    import torch

    from hardware.spec import load_spec
    from sim2real.deploy.loop import LoopConfig
    from sim2real.deploy.runner import DeployOptions, deploy
    from sim2real.evaluate import EvalTarget, evaluate
    from sim2real.train.cache import cached_reach_policy

    torch.set_num_threads(1)
    parser = argparse.ArgumentParser()
    parser.add_argument("run", nargs="?", default=None)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument(
        "--backends",
        default="sim,mock",
        help="comma list; the ratio needs both (a timing rerun: mock)",
    )
    args = parser.parse_args()
    backends = [b for b in args.backends.split(",") if b]
    run = args.run or str(cached_reach_policy())
    spec = load_spec()
    machine = f"{platform.machine()} {os.cpu_count()} cpu"
    for dr in ("none", "default") if len(backends) > 1 else ():
        ev = evaluate(EvalTarget.load(run), episodes=args.episodes, dr=dr)
        emit(
            f"env_success_dr_{dr}",
            ev["success_rate"],
            "fraction",
            episodes=args.episodes,
            machine=machine,
        )
    results = {}
    for backend in backends:
        t0 = time.perf_counter()
        res = deploy(run, spec, DeployOptions(backend=backend), LoopConfig(episodes=args.episodes))
        s = res.summary()
        results[backend] = s
        emit(
            f"deploy_{backend}_success",
            s["success_rate"],
            "fraction",
            episodes=s["episodes"],
            wall_s=round(time.perf_counter() - t0, 1),
        )
        emit(f"deploy_{backend}_mean_final_distance_m", round(s["mean_final_distance_m"], 5), "m")
        emit(f"deploy_{backend}_loop_hz", round(s["loop_hz"], 3), "Hz", target=20)
        jitter = s["period_jitter_ms"]
        emit(
            f"deploy_{backend}_jitter_p99_ms",
            round(jitter["p99"], 3),
            "ms",
            p50=round(jitter["p50"], 3),
            max=round(jitter["max"], 3),
            target=5.0,
            passed=jitter["p99"] <= 5.0,
        )
        emit(
            f"deploy_{backend}_sections_ms",
            {k: {q: round(v, 3) for q, v in d.items()} for k, d in s["sections_ms"].items()},
            "ms",
        )
    if not {"sim", "mock"} <= set(results):
        return
    sim, mock = results["sim"]["success_rate"], results["mock"]["success_rate"]
    ratio = mock / sim if sim > 0 else float("nan")
    emit(
        "mock_vs_sim_success",
        round(ratio, 3),
        "ratio",
        target=0.9,
        passed=bool(np.isfinite(ratio) and ratio >= 0.9),
    )


if __name__ == "__main__":
    main()
