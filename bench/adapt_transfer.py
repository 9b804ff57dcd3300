"""The transfer table of issue 20: per policy and plant preset, mock success / sim success
zero-shot and after ``sim2real adapt``, with Wilson intervals, and adapt's wall time.

Prints one JSON object per cell (``policy``, ``plant``, then the figures) and a final line per
cell with ``pass`` against the targets: after adapt, mock/sim >= 0.9; adapt's wall time, arm time
included, <= 20 min on this 2-core CPU, for adapt as a user runs it (its default 20 episodes
before and after; a 100-episode cell's deploys are scaled to that by their measured time per
episode, and the cell also prints its whole measured wall).

A cell is one ``sim2real adapt POLICY --backend mock --plant PLANT --episodes N --minutes M``
(subprocess, into ``runs/bench-adapt/<policy>-<plant>``; re-running continues a cell), whose
zero-shot and evaluate stages are the mock successes, and two ``evaluate`` runs in the policy's
own simulator with DR ``none`` over N held-out episodes: the original policy (its spec) and the
adapted one (the fitted spec it carries) are the denominators. The mock deploys replay those
held-out episodes' objects (``--placements held-out``), so each ratio is paired. Wall time is the sum of adapt's
stages (zero-shot deploy, recording, fits, fine-tune, export, evaluate deploy); the sim
evaluations are not part of adapt.

    MUJOCO_GL=egl nice -n 10 .venv/bin/python bench/adapt_transfer.py \\
        [--policies reach-ppo reach-ddpg] [--plants mild moderate hard] [--episodes 100] \\
        [--minutes 10] [--watchdog-s 1]

The full table (2 policies x 3 plants x 100 episodes x 2 deploys) takes hours; ``--policies``,
``--plants`` and ``--episodes`` run part of it. A policy is a shipped name with a checkpoint or
a run directory.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from support.load import emit_row

os.environ.setdefault("MUJOCO_GL", "egl")

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

RATIO_TARGET = 0.9
WALL_TARGET_S = 20 * 60.0
ADAPT_DEFAULT_EPISODES = 20  # `sim2real adapt --episodes` default


def emit(row: dict[str, Any]) -> None:
    emit_row(row)


def sim_success(policy: str | Path, episodes: int) -> dict[str, Any]:
    from sim2real.evaluate import EvalTarget, evaluate
    from sim2real.policies import resolve_policy

    ev = evaluate(EvalTarget.load(resolve_policy(str(policy))), episodes=episodes, dr="none")
    return {
        "success_rate": round(float(ev["success_rate"]), 4),
        "wilson95": [round(float(v), 4) for v in ev["success_rate_wilson95"]],
    }


def run_adapt(
    policy: str,
    plant: str,
    out: Path,
    episodes: int,
    minutes: float,
    watchdog_s: float | None,
    placements: str,
) -> dict[str, Any]:
    cmd = [
        sys.executable, "-m", "sim2real", "adapt", policy, "--backend", "mock", "--plant", plant,
        "--out", str(out), "--episodes", str(episodes), "--minutes", str(minutes), "--json",
        "--placements", placements,
    ]  # fmt: skip
    if watchdog_s is not None:
        cmd += ["--watchdog-s", str(watchdog_s)]
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO)
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(
            f"adapt {policy} on {plant} failed ({res.returncode}): {res.stderr[-800:]}"
        )
    rows = {}
    for line in res.stdout.splitlines():
        if line.startswith("{"):
            row = json.loads(line)
            rows[row["stage"]] = row
    rows["_process_wall_s"] = {"value": wall}
    return rows


def ratio(mock: float, sim: float) -> float | None:
    return round(mock / sim, 4) if sim > 0 else None


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policies", nargs="+", default=["reach-ppo", "reach-ddpg"])
    p.add_argument("--plants", nargs="+", default=["mild", "moderate", "hard"])
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--minutes", type=float, default=10.0, help="adapt's fine-tune budget")
    p.add_argument("--root", type=Path, default=REPO / "runs" / "bench-adapt")
    p.add_argument(
        "--watchdog-s",
        type=float,
        default=None,
        help="the mock's watchdog (default: the spec's 0.25 s); longer on a shared machine, where "
        "a start-up pause can trip it: the table measures transfer, bench/deploy_mock.py timing",
    )
    p.add_argument(
        "--placements", default="held-out", choices=("held-out", "loop"),
        help="the mock deploys' objects: the held-out episodes the sim figures are measured on "
        "(paired, default) or the loop's own draws",
    )  # fmt: skip
    a = p.parse_args()
    failed = False
    for policy in a.policies:
        sim0 = sim_success(policy, a.episodes)
        for plant in a.plants:
            out = a.root / f"{Path(policy).name}-{plant}-n{a.episodes}"
            rows = run_adapt(policy, plant, out, a.episodes, a.minutes, a.watchdog_s, a.placements)
            zero, after = rows["zero_shot"], rows["evaluate"]
            sim1 = sim_success(out / "policy.onnx", a.episodes)
            stage_s = {
                k: float(r.get("stage_wall_s", 0.0))
                for k, r in rows.items()
                if not k.startswith("_")
            }
            wall = sum(stage_s.values())
            deploy_s = stage_s.get("zero_shot", 0.0) + stage_s.get("evaluate", 0.0)
            cell = {
                "policy": policy,
                "plant": plant,
                "episodes": a.episodes,
                "minutes": a.minutes,
                "watchdog_s": a.watchdog_s,
                "placements": a.placements,
                "sim_zero_shot": sim0,
                "mock_zero_shot": {
                    "success_rate": zero["success_rate"],
                    "wilson95": zero["success_wilson95"],
                },
                "ratio_zero_shot": ratio(zero["success_rate"], sim0["success_rate"]),
                "sim_adapted": sim1,
                "mock_adapted": {
                    "success_rate": after["success_rate"],
                    "wilson95": after["success_wilson95"],
                },
                "ratio_adapted": ratio(after["success_rate"], sim1["success_rate"]),
                "adapt_wall_s": round(wall, 1),
                # the two N-episode deploys are the measurement; the rest is what adapting costs
                "deploy_wall_s": round(deploy_s, 1),
                "record_fit_finetune_export_wall_s": round(wall - deploy_s, 1),
                "stage_wall_s": {k: round(v, 1) for k, v in stage_s.items()},
                "finetune_steps": rows["finetune"].get("steps"),
                "fitted_offsets_rad": rows["fit"].get("joint_offset_rad"),
                "fitted_link_change_mm": rows["fit"].get("link_change_mm"),
            }
            ok_ratio = cell["ratio_adapted"] is not None and cell["ratio_adapted"] >= RATIO_TARGET
            # the wall target is for adapt as a user runs it (20 episodes before and after); a
            # 100-episode cell spends most of its time measuring, so its wall is judged on the
            # adapting stages plus its deploys' time per episode at adapt's default episode count
            per_episode_s = deploy_s / (2 * a.episodes)
            at_default_s = (wall - deploy_s) + per_episode_s * 2 * ADAPT_DEFAULT_EPISODES
            cell["adapt_wall_at_default_episodes_s"] = round(at_default_s, 1)
            ok_wall = at_default_s <= WALL_TARGET_S
            failed |= not (ok_ratio and ok_wall)
            print(json.dumps({**cell, "pass": ok_ratio and ok_wall}), flush=True)  # the detail
            emit(curated(cell))  # the figure the pages show
    return 1 if failed else 0


def curated(cell: dict[str, Any]) -> dict[str, Any]:
    """A cell as the benchmark pages show it: mock ÷ sim after adapt, with the zero-shot ratio,
    the mock success and adapt's wall at its default episode count in the note."""
    n, after = cell["episodes"], cell["mock_adapted"]
    lo, hi = after["wilson95"]
    minutes = cell.get("adapt_wall_at_default_episodes_s", cell["adapt_wall_s"]) / 60.0
    return {
        "metric": "mock_over_sim_after_adapt",
        "label": f"`{cell['policy']}` on the `{cell['plant']}` plant",
        "value": cell["ratio_adapted"],
        "unit": "ratio",
        "policy": cell["policy"],
        "plant": cell["plant"],
        "target": f">= {RATIO_TARGET}",
        "note": (
            f"zero-shot {cell['ratio_zero_shot']:.2f}; mock after adapt "
            f"{after['success_rate']:.2f} [{lo:.2f}, {hi:.2f}] on {n} paired episodes; adapt at "
            f"its default 20 episodes {minutes:.1f} min"
        ),
        "episodes": n,
        "table": f"Mock ÷ sim success after `sim2real adapt`, {n} paired episodes per figure",
    }


if __name__ == "__main__":
    sys.exit(main())
