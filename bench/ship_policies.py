"""Ship a measured policy: export a run to ONNX (parity-checked) into ``sim2real/policies/``,
measure its held-out success in its env (DR ``default`` and ``none``, Wilson intervals) and
write its card. Parity is checked on 1,000 observations from the run's env (for a pixel policy,
rendered frames); a discrete policy (Kuka's 7 actions) must choose the torch policy's action on
every one, and its card records the largest logit (DQN: Q-value) difference too. ``sim2real policies`` lists what is shipped; every command takes the name.

    .venv/bin/python bench/ship_policies.py RUN_DIR NAME --summary "what it is for" [--checkpoint]
        [--task NAME]  (envs without a task name, e.g. Kuka's: ``--task grasp``)

``--checkpoint`` also ships the run's final SB3 model as ``<name>.zip`` (actor, critic,
optimiser) and ``<name>.train.json`` (the run's config and its observation-normalisation
statistics as numbers), named in the card's ``checkpoint``: ``sim2real adapt`` fine-tunes from
them. ``--add-checkpoint`` adds them to an already shipped policy without measuring again, after
checking that the run's policy is the shipped ONNX (parity). ``--remeasure WHY`` measures a
shipped policy again from its file (RUN is ``-``) and updates its card, saying why: a change
that makes a published figure stale re-measures it.

Prints JSON lines; the card keeps the figures with the date and the machine. With
``--record training`` the held-out figures also become records, which the benchmark pages show
(``bench/pages.py``; ``tests/bench/test_pages.py`` holds cards and records to each other).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
from pathlib import Path

from support.load import emit_row

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


def emit(metric: str, value: object, unit: str = "", **extra: object) -> None:
    """A figure: printed, and recorded with ``--record``."""
    emit_row({"metric": metric, "value": value, "unit": unit, **extra})


def say(metric: str, value: object, unit: str = "", **extra: object) -> None:
    """What the shipping did (sizes, parity): printed only, never a benchmark record."""
    print(json.dumps({"metric": metric, "value": value, "unit": unit, **extra}), flush=True)


def ship_checkpoint(run: str, name: str) -> dict[str, object]:
    """``<name>.zip`` (the run's final model) and ``<name>.train.json`` beside the ONNX."""
    import pickle

    from hardware.atomic import atomic_write_bytes, atomic_write_text
    from sim2real.adapt.checkpoint import train_stats_text
    from sim2real.policies import SHIPPED_DIR
    from sim2real.train.rundir import RunDir

    rd = RunDir(run)
    config = rd.read_config()
    status = rd.read_status()
    if not status.get("finished"):
        raise SystemExit(f"{run} has not finished training")
    model, vn_path = rd.policy_files()
    vn = None
    if vn_path is not None:
        with vn_path.open("rb") as fh:  # our own run's file, not package data
            vn = pickle.load(fh)
    steps = int(status["steps_done"])
    zip_path = atomic_write_bytes(SHIPPED_DIR / f"{name}.zip", model.read_bytes())
    stats = atomic_write_text(
        SHIPPED_DIR / f"{name}.train.json",
        train_stats_text(config, steps, int(status.get("segments", 1)), vn),
    )
    size = zip_path.stat().st_size + stats.stat().st_size
    say("checkpoint_shipped", name, "", bytes=size, steps=steps)
    return {"model": zip_path.name, "stats": stats.name, "steps": steps}


def measure(policy_file: Path, name: str, episodes: int) -> dict[str, object]:
    """The card's figures: held-out success from the exported file under DR default and none."""
    from sim2real.evaluate import EvalTarget, evaluate

    target = EvalTarget.load(policy_file)
    figures: dict[str, object] = {}
    for dr in ("default", "none"):
        ev = evaluate(target, episodes=episodes, dr=dr)
        figures[f"env_success_dr_{dr}"] = round(float(ev["success_rate"]), 4)
        figures[f"env_success_dr_{dr}_ci95"] = [
            round(float(v), 4) for v in ev["success_rate_wilson95"]
        ]
        emit(  # the card's own numbers: bench/pages.py checks the records against the card
            f"env_success_dr_{dr}",
            figures[f"env_success_dr_{dr}"],
            "fraction",
            label=f"held-out success, DR `{dr}`",
            ci95=figures[f"env_success_dr_{dr}_ci95"],
            policy=name,
            episodes=episodes,
            task=str(target.policy.meta.task),
            env=target.env_id,
            table="Shipped policies: held-out success in their env",
        )
    figures["episodes"] = episodes
    return figures


def main() -> None:
    import torch

    from hardware.atomic import atomic_write_bytes
    from sim2real.evaluate import EvalTarget
    from sim2real.evaluate.parity import check_parity, parity_check
    from sim2real.export.exporter import export_policy
    from sim2real.policies import SHIPPED_DIR

    torch.set_num_threads(1)
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run")
    p.add_argument("name")
    p.add_argument("--summary", default="")
    p.add_argument("--task", help="the card's task (default: the env's own, e.g. reach)")
    p.add_argument("--episodes", type=int, default=200)
    p.add_argument("--checkpoint", action="store_true", help="also ship the SB3 checkpoint")
    p.add_argument(
        "--add-checkpoint", action="store_true", help="only add the checkpoint to a shipped card"
    )
    p.add_argument(
        "--parity-tol",
        type=float,
        default=None,
        help="largest allowed action difference ONNX vs torch (default: the exporter's 1e-5); "
        "a policy whose normalised inputs are badly scaled (a near-constant field) may need more",
    )
    p.add_argument(
        "--remeasure",
        metavar="WHY",
        help="only measure a shipped policy again (its file, not a run: pass '-' as RUN) and "
        "update its card's figures, saying why (e.g. the env's physics changed)",
    )
    a = p.parse_args()
    out = SHIPPED_DIR / f"{a.name}.onnx"
    if a.remeasure:
        card_path = SHIPPED_DIR / f"{a.name}.json"
        card = json.loads(card_path.read_text())
        card["figures"] = measure(SHIPPED_DIR / card["file"], a.name, a.episodes)
        card["trained"]["measured"] = dt.date.today().isoformat()
        card["trained"]["remeasured_because"] = a.remeasure
        atomic_write_bytes(card_path, (json.dumps(card, indent=2) + "\n").encode())
        return
    if a.add_checkpoint:
        card_path = SHIPPED_DIR / f"{a.name}.json"
        card = json.loads(card_path.read_text())
        diff = parity_check(a.run, out, 1000)
        say("parity_run_vs_shipped_max_abs_action_diff", diff, "1", name=a.name)
        if diff > 1e-4:
            raise SystemExit(f"{a.run} is not the run shipped as {a.name} (action diff {diff})")
        card["checkpoint"] = ship_checkpoint(a.run, a.name)
        atomic_write_bytes(card_path, (json.dumps(card, indent=2) + "\n").encode())
        return
    export_policy(a.run, "onnx", out)
    tol = {} if a.parity_tol is None else {"tolerance": a.parity_tol}
    parity = check_parity(a.run, out, 1000, **tol)
    diff = parity.max_abs_action_diff
    say("parity_max_abs_action_diff", diff, "1", name=a.name)
    if parity.max_abs_score_diff is not None:  # discrete: the actions agreed on every frame
        say(
            "parity_max_abs_score_diff",
            parity.max_abs_score_diff,
            "logit or Q",
            name=a.name,
            observations=parity.observations,
            action_disagreements=parity.action_disagreements,
        )
    target = EvalTarget.load(out)
    figures = measure(out, a.name, a.episodes)
    import gymnasium as gym

    config = json.loads((Path(a.run) / "config.json").read_text())
    status = json.loads((Path(a.run) / "status.json").read_text())
    card = {
        "file": out.name,
        "task": a.task or str(gym.spec(target.env_id).kwargs.get("task", "")),
        "env_id": target.env_id,
        "algo": config["algo"],
        "summary": a.summary,
        "figures": figures,
        "trained": {
            "dr": config["dr"],
            "steps": status.get("steps_done"),  # what it trained, not the config's bound
            "wall_min": round(float(status.get("wall_s", 0.0)) / 60.0, 1),
            "seed": config.get("seed"),
            "measured": dt.date.today().isoformat(),
            "machine": f"{platform.machine()} {os.cpu_count()} cpu",
            "parity_max_abs_action_diff": diff,
            **(
                {}
                if parity.max_abs_score_diff is None
                else {"parity_max_abs_score_diff": parity.max_abs_score_diff}
            ),
        },
    }
    if a.checkpoint:
        card["checkpoint"] = ship_checkpoint(a.run, a.name)
    atomic_write_bytes(SHIPPED_DIR / f"{a.name}.json", (json.dumps(card, indent=2) + "\n").encode())
    say("shipped", a.name, "", bytes=out.stat().st_size)


if __name__ == "__main__":
    main()
