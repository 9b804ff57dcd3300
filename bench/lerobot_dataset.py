"""A 10-episode pick dataset recorded from the mock arm's loop (``sim2real deploy --backend mock
--record-dataset``; ``--source evaluate`` takes the simulator's evaluation rollouts instead),
loaded by LeRobot's own ``LeRobotDataset`` (issue 17).

LeRobot needs numpy >= 2 and Python >= 3.12; the standalone ``lerobot-dataset`` package reads the
same v3.0 format on Python 3.11 but pins packaging < 26, which clashes with this venv. So the
check runs in a separate venv under ``.cache/lerobot-venv`` (made on first run, 7.4 GB: PyPI's
torch for Linux carries the CUDA libraries, and torchvision 0.23 is the last with the PyAV
video reader that ``lerobot-dataset`` falls back to without torchcodec).

Prints JSON lines: the recording (frames, seconds), then what LeRobot's class found: episodes,
frames, fps, features, task, and the video frames it decoded compared with our own reader's
(mean absolute difference in [0, 1] pixel units; a frame from the wrong episode or step differs
by far more). Exits 1 if any figure disagrees.

Run: .venv/bin/python bench/lerobot_dataset.py [--source mock|evaluate] [--run POLICY] [--episodes 10]
The mock source deploys the shipped ``pick-ppo`` by default; the evaluate source, without --run,
trains a tiny PPO pick policy (the format, not the policy, is under test).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np
from support.load import emit_row

ROOT = Path(__file__).resolve().parent.parent
CACHE = ROOT / ".cache"
VENV = CACHE / "lerobot-venv"
# The versions validated against (docs/studies/deploy.md, "LeRobot datasets", names them).
LEROBOT_PINS = ("lerobot-dataset==0.4.4", "torch==2.8.0", "torchvision==0.23.0")


def ensure_venv() -> Path:
    python = VENV / "bin" / "python"
    if python.exists():
        return python
    print(
        json.dumps({"setup": f"creating {VENV.relative_to(ROOT)} with {list(LEROBOT_PINS)}"}),
        flush=True,
    )
    subprocess.run([sys.executable, "-m", "venv", str(VENV)], check=True)
    subprocess.run(
        [str(python), "-m", "pip", "install", "--quiet", "--progress-bar", "off", *LEROBOT_PINS],
        check=True,
    )
    return python


def tiny_pick_run() -> Path:
    """A real run dir for Arm3Pick-v0 (a few hundred PPO steps), cached between runs."""
    from sim2real.train import resolve_config, train

    run = CACHE / "bench" / "pick-ppo-tiny"
    if (run / "model.zip").exists():
        return run
    cfg = resolve_config(
        "pick",
        "ppo",
        run,
        steps=256,
        progress=False,
        overrides=["n_envs=2", "n_steps=64", "batch_size=64", "n_epochs=1"],
    )
    train(cfg)
    return run


def reference_frames(dataset: Path, out: Path) -> int:
    """Our reader's frames for the first, middle and last step of a few episodes."""
    from sim2real.datasets import LeRobotDataset

    ds = LeRobotDataset.open(dataset)
    n = len(ds.episodes)
    ref: dict[str, np.ndarray] = {}
    for ep in sorted({0, n // 2, n - 1}):
        for cam in ds.cameras:
            frames = list(ds.video_frames(ep, cam))
            for i in sorted({0, len(frames) // 2, len(frames) - 1}):
                ref[f"{ep}|{i}|{cam}"] = frames[i]
    np.savez(out, **ref)  # type: ignore[arg-type]
    return len(ref)


def main() -> int:
    import torch

    from sim2real.cli.main import main as cli

    torch.set_num_threads(1)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", choices=("mock", "evaluate"), default="mock")
    ap.add_argument("--run", help="pick policy: run dir, exported file or shipped name")
    ap.add_argument("--episodes", type=int, default=10)
    args = ap.parse_args()
    python = ensure_venv()
    out = CACHE / "bench" / f"lerobot-pick-{args.source}"
    if args.source == "mock":
        import shutil

        run = args.run or "pick-ppo"
        shutil.rmtree(out, ignore_errors=True)  # deploy refuses an existing dataset
        command = ["deploy", run, "--backend", "mock", "--episodes", str(args.episodes)]
    else:
        run = args.run or str(tiny_pick_run())
        command = ["evaluate", run, "--episodes", str(args.episodes), "--overwrite"]
    buf = io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(buf):
        code = cli([*command, "--record-dataset", str(out), "--json"])
    wall_s = time.perf_counter() - t0
    if code != 0:
        print(json.dumps({"error": f"sim2real {command[0]} exited {code}"}), flush=True)
        return 1
    rec = json.loads(buf.getvalue().strip().splitlines()[-1])
    info = json.loads((out / "meta" / "info.json").read_text())
    emit_row(
        {
            "metric": "lerobot_record",
            "bench": "lerobot_record",
            "source": args.source,
            "policy": run,
            "env": "Sim2Real/Arm3Pick-v0",
            "episodes": rec["episodes"],
            "frames": info["total_frames"],
            "success_rate": rec["success_rate"],
            "wall_s": round(wall_s, 1),
            "machine": f"{platform.machine()} {os.cpu_count()} cpu",
        }
    )
    ref = out.parent / f"lerobot-pick-{args.source}-ref.npz"
    n_ref = reference_frames(out, ref)
    check = subprocess.run(
        [str(python), str(ROOT / "bench" / "support" / "lerobot_check.py"), str(out), str(ref)],
        capture_output=True,
        text=True,
    )
    if check.returncode != 0:
        print(
            json.dumps({"error": "LeRobotDataset failed", "stderr": check.stderr[-2000:]}),
            flush=True,
        )
        return 1
    got = json.loads(check.stdout.strip().splitlines()[-1])
    want = {
        "num_episodes": args.episodes,
        "num_frames": info["total_frames"],
        "len": info["total_frames"],
        "fps": info["fps"],
        "features": sorted(info["features"]),
        "video_keys": ["observation.images.cam_left", "observation.images.cam_right"],
        "task": "pick up the cube and lift it to the goal",
        "video_frames_checked": n_ref,
        # 8 future actions from 3 steps before an episode's end: 5 past it are padding.
        "action_chunk_shape": [8, info["features"]["action"]["shape"][0]],
        "action_chunk_padded": 5,
        "image_history_shape": [
            2,
            3,
            *info["features"]["observation.images.cam_left"]["shape"][:2],
        ],
    }
    mismatch = {k: (got.get(k), v) for k, v in want.items() if got.get(k) != v}
    ok = not mismatch and got["video_mean_abs_diff"] < 1e-3 and got["codebase_version"] == "v3.0"
    emit_row(
        {"metric": "lerobot_load", "bench": "lerobot_load", "ok": ok, "mismatch": mismatch, **got}
    )
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
