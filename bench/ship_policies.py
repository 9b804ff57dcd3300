"""Ship a measured policy: export a run to ONNX (parity-checked) into ``sim2real/policies/``,
measure its held-out success in its env (DR ``default`` and ``none``, Wilson intervals) and
write its card. ``sim2real policies`` lists what is shipped; every command takes the name.

    .venv/bin/python bench/ship_policies.py RUN_DIR NAME --summary "what it is for"

Prints JSON lines; the card keeps the figures with the date and the machine.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


def emit(metric: str, value: object, unit: str = "", **extra: object) -> None:
    print(json.dumps({"metric": metric, "value": value, "unit": unit, **extra}), flush=True)


def main() -> None:
    import torch

    from hardware.atomic import atomic_write_bytes
    from sim2real.evaluate import EvalTarget, evaluate
    from sim2real.evaluate.parity import parity_check
    from sim2real.export.exporter import export_policy
    from sim2real.policies import SHIPPED_DIR

    torch.set_num_threads(1)
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run")
    p.add_argument("name")
    p.add_argument("--summary", default="")
    p.add_argument("--episodes", type=int, default=200)
    a = p.parse_args()
    out = SHIPPED_DIR / f"{a.name}.onnx"
    export_policy(a.run, "onnx", out)
    diff = parity_check(a.run, out, 1000)
    emit("parity_max_abs_action_diff", diff, "1", name=a.name)
    target = EvalTarget.load(out)
    figures: dict[str, object] = {}
    for dr in ("default", "none"):
        ev = evaluate(target, episodes=a.episodes, dr=dr)
        figures[f"env_success_dr_{dr}"] = round(float(ev["success_rate"]), 4)
        figures[f"env_success_dr_{dr}_ci95"] = [
            round(float(v), 4) for v in ev["success_rate_wilson95"]
        ]
        emit(
            f"env_success_dr_{dr}", ev["success_rate"], "fraction", ci95=ev["success_rate_wilson95"]
        )
    figures["episodes"] = a.episodes
    import gymnasium as gym

    config = json.loads((Path(a.run) / "config.json").read_text())
    card = {
        "file": out.name,
        "task": str(gym.spec(target.env_id).kwargs.get("task", "")),
        "env_id": target.env_id,
        "algo": config["algo"],
        "summary": a.summary,
        "figures": figures,
        "trained": {
            "dr": config["dr"],
            "steps": config.get("steps"),
            "seed": config.get("seed"),
            "measured": dt.date.today().isoformat(),
            "machine": f"{platform.machine()} {os.cpu_count()} cpu",
            "parity_max_abs_action_diff": diff,
        },
    }
    atomic_write_bytes(SHIPPED_DIR / f"{a.name}.json", (json.dumps(card, indent=2) + "\n").encode())
    emit("shipped", a.name, "", bytes=out.stat().st_size)


if __name__ == "__main__":
    main()
