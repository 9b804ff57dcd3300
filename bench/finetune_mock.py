"""Fine-tuning on the mock arm: success against arm minutes, and the loop's timing while learning.

A shipped (or run-dir) off-policy policy is fine-tuned with ``sim2real finetune``'s own code on the
mock arm built from a plant preset, for M arm minutes per seed. Every few arm minutes the loop runs
N deterministic evaluation episodes (the first at minute 0: the zero-shot success; a last one after
the budget), so the curve is success against arm minutes, with Wilson 95 % intervals. Arm minutes
count everything the arm did (training and evaluation episodes, resets and homing).

JSON lines: one per evaluation block (``finetune_eval_success``), the loop's timing while the
learner trains (``finetune_loop``: rate, period jitter p50/p99, late periods, watchdog trips), the
learner's updates, the safety stats; then the learning-curve PNG path (matplotlib, Agg).

    nice -n 5 .venv/bin/python bench/finetune_mock.py reach-ddpg --plant hard --minutes 5
    nice -n 5 .venv/bin/python bench/finetune_mock.py reach-ddpg --plant hard --minutes 15 --seeds 3

``--adapted DIR`` fine-tunes what ``sim2real adapt`` made (its ``finetune/`` run with its fitted spec
and joint calibration) and counts the arm time adapt's identification took (its ``record``
stage) in the budget and on the curve, so ``--minutes`` stays the whole arm time that learning
used. Adapt's zero-shot and evaluation deploys are measurements, not counted.

    nice -n 5 .venv/bin/python bench/finetune_mock.py --adapted runs/adapt-pick-ddpg-hard \
        --plant hard --minutes 15 --eval-every 3 --eval-episodes 20 --actor-update advantage
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import time
from pathlib import Path
from typing import Any

from support.load import emit_row

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


def emit(metric: str, value: object, unit: str = "", **extra: object) -> None:
    emit_row({"metric": metric, "value": value, "unit": unit, **extra})


def _plot(curves: dict[int, list[dict[str, Any]]], target: float | None, path: Path,
          title: str) -> None:  # fmt: skip
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.0, 4.0))
    for seed, evals in curves.items():
        x = [e["arm_min"] for e in evals]
        y = [e["success"] for e in evals]
        lo = [e["success"] - e["wilson95"][0] for e in evals]
        hi = [e["wilson95"][1] - e["success"] for e in evals]
        ax.errorbar(x, y, yerr=[lo, hi], marker="o", capsize=3, label=f"seed {seed}")
    if target is not None:
        ax.axhline(target, color="grey", linestyle="--", label="0.9 x sim success")
    ax.set_xlabel("arm minutes")
    ax.set_ylabel("success (deterministic actor)")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


SETTING_FILE = "bench_setting.json"  # a seed's run folder: the bench setting that made it


def _setting(common: dict[str, Any]) -> dict[str, Any]:
    """What makes two seeds' curves comparable: every option, not when or where they ran."""
    return {k: v for k, v in common.items() if k not in ("date", "machine")}


def _finished_seeds(
    out: Path, tag: str, setting: dict[str, Any], offset_min: float = 0.0
) -> dict[int, list[dict[str, Any]]]:
    """The evaluation blocks of finished runs ``{tag}-s<seed>`` under ``out`` made with the
    same ``setting``, their arm minutes shifted by ``offset_min`` (adapt's identification)."""
    from sim2real.evaluate.stats import wilson_interval

    want = json.loads(json.dumps(setting, sort_keys=True))
    curves: dict[int, list[dict[str, Any]]] = {}
    for path in sorted(out.glob(f"{tag}-s*/finetune.json")):
        seed = path.parent.name.removeprefix(f"{tag}-s")
        made_by = path.with_name(SETTING_FILE)
        if not seed.isdigit() or not made_by.is_file() or json.loads(made_by.read_text()) != want:
            continue
        state = json.loads(path.read_text())
        if not state.get("finished"):
            continue
        curves[int(seed)] = [
            {"arm_min": b["arm_min"] + offset_min, "success": b["successes"] / b["n"],
             "wilson95": wilson_interval(b["successes"], b["n"])}
            for b in state["evals"] if b["n"]
        ]  # fmt: skip
    return curves


def _adapted(folder: Path, plant: str) -> dict[str, Any]:
    """What ``sim2real adapt --out FOLDER`` left for a fine-tune, as its ``status.json`` names
    it (``adapt.figures``): its run, fitted spec, joint calibration, the source policy's name
    and the arm minutes its recording took."""
    from sim2real.adapt.figures import FinetuneFigures, FitFigures, RecordFigures, StageResult

    status_path = folder / "status.json"
    if not status_path.is_file():
        raise SystemExit(f"error: --adapted {folder}: no status.json (not an adapt --out folder)")
    status = json.loads(status_path.read_text())
    missing = [s for s in ("record", "fit", "finetune") if s not in status.get("stages_done", [])]
    if missing:
        raise SystemExit(f"error: --adapted {folder}: stages {missing} not done")
    if status.get("plant") != plant:
        raise SystemExit(f"error: --adapted {folder} was fitted on plant {status.get('plant')!r}, "
                         f"not --plant {plant!r}")  # fmt: skip
    stage = {k: StageResult.from_json(k, status["figures"][k]) for k in ("record", "fit",
                                                                        "finetune")}  # fmt: skip
    fit, run = stage["fit"].figures, stage["finetune"].figures
    assert isinstance(fit, FitFigures) and isinstance(run, FinetuneFigures)
    record = stage["record"]
    return {
        "policy": str(folder / run.run_dir),
        "spec": folder / fit.spec,
        "joint_calibration": folder / fit.joint_calibration,
        "source": status["policy"],
        # the record stage's wall clock: the arm's excitation and sweep plus its start-up (an
        # upper bound on arm time); none where adapt took logs recorded earlier (--logs)
        "identification_min": record.stage_wall_s / 60.0
        if isinstance(record.figures, RecordFigures) else 0.0,
    }  # fmt: skip


def _reference(policy: str, spec: Any, opts: Any, episodes: int) -> dict[str, float]:
    """The same backend and env stepped by the exported policy with no learner at all: the
    loop's timing under this run's load, for the ratio against the timing while learning."""
    import numpy as np

    from sim2real.deploy.realtime import control_thread_priority
    from sim2real.export.policy import load_policy
    from sim2real.finetune.arm_env import ArmEnv, ArmEnvConfig
    from sim2real.policies import resolve_policy

    pol = load_policy(resolve_policy(policy))
    config = ArmEnvConfig(rate_hz=pol.meta.control_hz, start_timeout_s=30.0)
    env = ArmEnv.for_policy(policy, spec, opts, config)
    from hardware.errors import HardwareError

    successes, lost = [], 0
    try:
        with control_thread_priority(opts.realtime):
            for episode in range(episodes):
                try:  # as finetune does on a simulated arm: a load-starved episode is lost
                    obs, _ = env.reset(seed=1_000_000 + episode)
                    truncated = False
                    while not truncated:
                        obs, _, _, truncated, info = env.step(pol(obs))
                    successes.append(bool(info["is_success"]))
                except HardwareError:
                    lost += 1
        periods = np.asarray(env.periods_s)
        jitter = np.abs(periods - env.period_s) * 1e3
        return {
            "success": float(np.mean(successes)),
            "rate_hz": float(1.0 / periods.mean()),
            "p50_jitter_ms": float(np.percentile(jitter, 50)),
            "p99_jitter_ms": float(np.percentile(jitter, 99)),
            "late_fraction": env.overruns / len(periods),
            "lost_episodes": lost,
        }
    finally:
        env.close()


def main() -> None:
    from hardware.spec import load_spec
    from sim2real.deploy.runner import DeployOptions
    from sim2real.finetune.defaults import ACTOR_UPDATES, LEARNER_DEFAULTS
    from sim2real.finetune.runner import FinetuneOptions, finetune
    from sim2real.policies import shipped

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("policy", nargs="?", default="reach-ddpg")
    ap.add_argument("--plant", default="hard", help="mock plant preset or YAML")
    ap.add_argument("--minutes", type=float, default=5.0, help="arm minutes per seed")
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--seed-start", type=int, default=0, help="the first seed (runs in turn)")
    ap.add_argument("--algo", default=None)
    ap.add_argument("--mix-sim-buffer", action="store_true")
    ap.add_argument("--utd", type=float, default=LEARNER_DEFAULTS["utd"])
    ap.add_argument("--learning-starts", type=int, default=LEARNER_DEFAULTS["learning_starts"])
    ap.add_argument("--actor-starts", type=int, default=LEARNER_DEFAULTS["actor_starts"])
    ap.add_argument("--relabel", type=float, default=None, help="default: the task's")
    ap.add_argument("--noise-std", type=float, default=None, help="default: finetune's")
    ap.add_argument("--anchor", type=float, default=None, help="default: finetune's")
    ap.add_argument("--actor-update", choices=sorted(ACTOR_UPDATES), default="critic")
    ap.add_argument("--imitation-ratio", type=float, default=1.0)
    ap.add_argument("--noise-corr-steps", type=float, default=0.0)
    ap.add_argument("--gripper-noise-std", type=float, default=None)
    ap.add_argument("--eval-every", type=float, default=1.5, help="arm minutes")
    ap.add_argument("--eval-episodes", type=int, default=10)
    ap.add_argument("--watchdog-s", type=float, default=None, help="mock: relaxed watchdog")
    ap.add_argument("--spec", type=Path, default=None, help="an adapted policy's fitted spec")
    ap.add_argument("--joint-calibration", type=Path, default=None, help="and its calibration")
    ap.add_argument(
        "--adapted", type=Path, default=None,
        help="an adapt --out folder: fine-tune its run, with its fitted spec and calibration",
    )  # fmt: skip
    ap.add_argument("--out", type=Path, default=Path("runs/bench-finetune"))
    ap.add_argument(
        "--reference-episodes", type=int, default=10,
        help="episodes with no learner first, on the same backend (0: none)",
    )  # fmt: skip
    args = ap.parse_args()

    offset_min, source = 0.0, args.policy
    if args.adapted is not None:
        adapted = _adapted(args.adapted, args.plant)
        args.policy, args.spec = adapted["policy"], adapted["spec"]
        args.joint_calibration, source = adapted["joint_calibration"], adapted["source"]
        offset_min = adapted["identification_min"]
        if not args.minutes > offset_min:
            raise SystemExit(f"error: --minutes {args.minutes} leaves nothing after adapt's "
                             f"{offset_min:.2f} identification minutes")  # fmt: skip
    spec = load_spec(args.spec)
    card = shipped().get(source)
    sim_success = None
    if card is not None:
        sim_success = getattr(card, "figures", {}).get("env_success_dr_default")
    common = {
        "policy": args.policy, "plant": args.plant, "algo": args.algo or "source's",
        "mix_sim_buffer": args.mix_sim_buffer, "utd": args.utd, "actor_starts": args.actor_starts,
        "actor_update": args.actor_update, "imitation_ratio": args.imitation_ratio,
        "anchor": args.anchor, "noise_corr_steps": args.noise_corr_steps,
        "gripper_noise_std": args.gripper_noise_std,
        "adapted": None if args.adapted is None else args.adapted.name,
        "identification_arm_min": round(offset_min, 3),
        "watchdog_s": args.watchdog_s or spec.safety.watchdog_timeout_s,
        "machine": f"{platform.machine()} {os.cpu_count()} cpu",
        "date": time.strftime("%Y-%m-%d"),
    }  # fmt: skip
    name = Path(source).name + ("-adapted" if args.adapted is not None else "")
    tag = f"{name}-{args.plant}{'-mix' if args.mix_sim_buffer else ''}"
    tag += "" if args.actor_update == "critic" else f"-{args.actor_update}"
    curves: dict[int, list[dict[str, Any]]] = {}
    for seed in range(args.seed_start, args.seed_start + args.seeds):
        out = args.out / f"{tag}-s{seed}"
        if out.exists():
            shutil.rmtree(out)
        opts = DeployOptions(backend="mock", plant=args.plant, watchdog_s=args.watchdog_s,
                             joint_calibration=args.joint_calibration)  # fmt: skip
        ref = None
        if args.reference_episodes > 0:
            ref = _reference(args.policy, spec, opts, args.reference_episodes)
            emit("finetune_loop_reference", ref["rate_hz"], "Hz", seed=seed,
                 episodes=args.reference_episodes, **{k: v for k, v in ref.items()
                                                      if k != "rate_hz"}, **common)  # fmt: skip
        t0 = time.monotonic()
        fo = FinetuneOptions(
            policy=args.policy, out=out,
            deploy=opts,
            minutes=args.minutes - offset_min, algo=args.algo, mix_sim_buffer=args.mix_sim_buffer,
            utd=args.utd, learning_starts=args.learning_starts, actor_starts=args.actor_starts,
            relabel=args.relabel, noise_std=args.noise_std, keys=False, anchor=args.anchor,
            actor_update=args.actor_update, imitation_ratio=args.imitation_ratio,
            noise_corr_steps=args.noise_corr_steps, gripper_noise_std=args.gripper_noise_std,
            eval_every_min=args.eval_every, eval_episodes=args.eval_episodes, seed=seed,
            start_timeout_s=30.0,
        )  # fmt: skip
        summary = finetune(fo, spec).to_json()  # the figures as the records keep them
        wall_s = time.monotonic() - t0
        # what the learner used: the defaults where the options were left unset
        common.update(relabel=summary["relabel"], noise_std=summary["noise_std"])
        (out / SETTING_FILE).write_text(json.dumps(_setting(common), sort_keys=True))
        curves[seed] = [{**b, "arm_min": b["arm_min"] + offset_min} for b in summary["evals"]]
        for block in curves[seed]:
            emit("finetune_eval_success", block["success"], "fraction", seed=seed,
                 arm_min=round(block["arm_min"], 3), n=block["n"], wilson95=block["wilson95"],
                 **common)  # fmt: skip
        loop = summary["loop"]
        emit("finetune_loop", loop["rate_hz"], "Hz", seed=seed,
             p50_jitter_ms=loop["period_jitter_ms_p50"], p99_jitter_ms=loop["period_jitter_ms_p99"],
             late_periods=loop["late_periods"], watchdog_trips=loop["watchdog_trips"],
             late_fraction=loop["late_periods"] / max(summary["env_steps"], 1),
             **common)  # fmt: skip
        if ref is not None:  # the learner's cost on the loop, under this run's load
            emit("finetune_loop_vs_reference", loop["period_jitter_ms_p99"] / ref["p99_jitter_ms"],
                 "ratio (p99 jitter, learning / no learner)", seed=seed,
                 late_fraction_ratio=(loop["late_periods"] / max(summary["env_steps"], 1))
                 / max(ref["late_fraction"], 1e-9), **common)  # fmt: skip
        emit("finetune_run", summary["episodes"], "episodes", seed=seed,
             arm_min=round(summary["arm_s"] / 60.0 + offset_min, 3), wall_min=round(wall_s / 60.0, 3),
             env_steps=summary["env_steps"], learner_updates=summary["learner_updates"],
             actor_weight_updates=summary["actor_weight_updates"], safety=summary["safety"],
             stopped=summary["stopped"], sim_success=sim_success, **common)  # fmt: skip
    # the curve of every seed of this setting under --out, this invocation's and earlier ones'
    # (each seed's folder is remade when that seed runs): seeds can run in separate invocations
    curves = {**_finished_seeds(args.out, tag, _setting(common), offset_min), **curves}
    png = args.out / f"{tag}.png"
    target = None if sim_success is None else 0.9 * float(sim_success)
    how = f" after adapt ({offset_min:.1f} arm min identifying)" if args.adapted else ""
    _plot(curves, target, png, f"{source}{how} on the {args.plant} plant (mock arm)")
    emit("finetune_curve_png", str(png), "path", **common)


if __name__ == "__main__":
    main()
