"""Where SubprocVecEnv pays on robosuite: training speed with the envs in-process or in workers.

One robosuite step costs ~6 ms of CPU, so with the envs in worker processes a 2-core machine can
step two of them at once while the learner waits; but every step then crosses a pipe, and an
off-policy learner's updates run between steps on the main process anyway. This bench trains each
robosuite preset for a fixed number of env steps with ``vec_env`` dummy and subproc (same n_envs,
same seed), round-robin over ``--rounds`` rounds so load drifts hit both alike, and prints the
training speed (env steps per wall second, updates included, as ``sim2real train`` reports it)
and the subproc/dummy ratio per preset. A ratio above 1 is where subprocesses pay. Run it on an
otherwise idle machine: a second busy process takes the core the workers need.

Run: ``MUJOCO_GL=egl .venv/bin/python bench/robosuite_vec_env.py``
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from support.load import emit

from sim2real.train import resolve_config, train

# (env, algo, env steps per measurement): PPO sees three 2048-transition updates; the off-policy
# presets 3,000 transitions after their random warm-up.
CASES = (
    ("Sim2Real/RobosuiteReach-v0", "ppo", 6144),
    ("Sim2Real/RobosuiteReach-v0", "ddpg", 5000),
    ("Sim2Real/RobosuiteLift-v0", "sac", 5000),
)
VEC_ENVS = ("dummy", "subproc")


def speed(env_id: str, algo: str, steps: int, vec_env: str, root: Path) -> float:
    run = root / f"{algo}-{env_id.split('/')[1]}-{vec_env}"
    cfg = resolve_config(
        env_id, algo, run, steps=steps, progress=False, overrides=[f"vec_env={vec_env}"]
    )
    return train(cfg).steps_per_s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    rates: dict[tuple[str, str, str], list[float]] = {}
    load = round(os.getloadavg()[0], 2)
    with tempfile.TemporaryDirectory(prefix="rs-vec-") as tmp:
        for r in range(args.rounds):
            for env_id, algo, steps in CASES:
                for vec in VEC_ENVS:
                    root = Path(tmp) / f"r{r}"
                    rates.setdefault((env_id, algo, vec), []).append(
                        speed(env_id, algo, steps, vec, root)
                    )
    for env_id, algo, _ in CASES:
        med = {vec: statistics.median(rates[(env_id, algo, vec)]) for vec in VEC_ENVS}
        name = env_id.split("/")[1]
        for vec in VEC_ENVS:
            emit(f"train_steps_per_s_{vec}", round(med[vec], 1), "steps/s", env=name, algo=algo)
        emit(
            "subproc_over_dummy",
            round(med["subproc"] / med["dummy"], 3),
            "ratio",
            env=name,
            algo=algo,
            rounds=args.rounds,
            load_1min=[load, round(os.getloadavg()[0], 2)],
        )


if __name__ == "__main__":
    main()
