"""``compare`` on a tiny grid: every file written, local processes and Ray give one format."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from sim2real.compare import CompareConfig, run_compare
from sim2real.compare.jobs import run_job
from sim2real.compare.report import summarise
from sim2real.compare.runner import jobs_for, parse_overrides, parse_presets
from sim2real.errors import ConfigError, RunDirError, Sim2RealError

TINY = {
    "dqn": (
        "n_envs=2",
        "learning_starts=100",
        "buffer_size=1000",
        "batch_size=32",
        "log_interval=1",
    ),
    "ppo": ("n_envs=2", "n_steps=64", "batch_size=64", "n_epochs=2"),
}


def _files(out: Path, algos: list[str]) -> set[str]:
    return {
        "report.md",
        "results.json",
        "learning_curves.png",
        "final_success.png",
        *(f"diagnostics_{a}.png" for a in algos),
    }


def _shape(obj: Any) -> Any:
    """The key structure of a JSON value (values dropped): what 'same format' means."""
    if isinstance(obj, dict):
        return {k: _shape(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_shape(obj[0])] if obj and isinstance(obj[0], dict | list) else "list"
    return type(obj).__name__ if obj is not None else "null"


def test_local_backend_writes_every_file(tmp_path: Path) -> None:
    """About 20 s idle: four tiny trainings and their evaluations in two worker processes (each
    imports torch and SB3), the smallest grid that has seeds to pool and algorithms to compare."""
    algos = ["dqn", "ppo"]
    cfg = CompareConfig(
        env="reach",
        algos=tuple(algos),
        seeds=2,
        steps=128,
        out=str(tmp_path / "rep"),
        workers=2,
        eval_episodes=4,
        overrides=TINY,
        presets={"ppo": "ppo_default"},  # instead of reach's own ppo_reach
    )
    files = run_compare(cfg)
    out = tmp_path / "rep"
    assert _files(out, algos) <= {p.name for p in out.iterdir()}
    for p in out.glob("*.png"):
        assert p.read_bytes()[:4] == b"\x89PNG"
    results = json.loads(files["results"].read_text())
    assert [(j["algo"], j["seed"]) for j in results["jobs"]] == [
        (a, s) for s in (0, 1) for a in algos
    ]
    for job in results["jobs"]:
        assert job["eval"]["episodes"] == 4 and job["steps"] >= 128
        # Paths inside the report folder are relative: the folder can be committed and moved.
        assert job["run_dir"] == f"runs/{job['algo']}-s{job['seed']}"
        assert job["eval"]["policy"] == job["run_dir"] and (out / job["run_dir"]).is_dir()
        assert len(job["curves"]["learning"]["success_rate"]) == 30
    diag = results["jobs"][0]["curves"]["diagnostics"]  # dqn seed 0
    assert set(diag) == {"rollout/exploration_rate", "train/q_mean", "train/loss"}
    assert any(v is not None for v in diag["rollout/exploration_rate"])
    assert set(results["summary"]) == set(algos)
    report = files["report"].read_text()
    for a in algos:
        assert f"| {a} | 2 |" in report and f"diagnostics_{a}.png" in report
    assert "ppo: `ppo_default`" in report and results["config"]["presets"] == {"ppo": "ppo_default"}
    for a, preset in (("ppo", "ppo_default"), ("dqn", "dqn_reach")):
        train_cfg = json.loads((out / "runs" / f"{a}-s0" / "config.json").read_text())["train"]
        assert train_cfg["preset"] == preset
    with pytest.raises(RunDirError, match="already holds runs"):
        run_compare(cfg)


@pytest.mark.slow  # Ray's start-up: 30 s idle, 110 s on a loaded 2-core machine (CI runs it)
def test_ray_backend_on_two_local_workers_gives_the_same_format(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    cfg = CompareConfig(
        env="reach",
        algos=("ppo",),
        seeds=2,
        steps=128,
        out=str(tmp_path / "ray"),
        backend="ray",
        workers=2,
        eval_episodes=2,
        overrides={"ppo": TINY["ppo"]},
    )
    files = run_compare(cfg)
    ray_results = json.loads(files["results"].read_text())
    assert ray_results["config"]["backend"] == "ray"
    assert [j["seed"] for j in ray_results["jobs"]] == [0, 1]
    # The local backend runs this same job function in a worker process: same seed, same
    # budget, so the record must have the same shape and the same figures.
    job = jobs_for(cfg)[1]
    local = run_job({**job, "run_dir": str(tmp_path / "local-s1")})
    remote = ray_results["jobs"][1]
    assert _shape(local) == _shape(remote)
    assert local["eval"]["success_rate"] == remote["eval"]["success_rate"]
    assert local["eval"]["mean_return"] == pytest.approx(remote["eval"]["mean_return"], rel=1e-6)


def test_jobs_run_seed_major_so_an_early_stop_still_covers_every_algorithm(tmp_path: Path) -> None:
    cfg = CompareConfig(
        env="reach", algos=("ppo", "dqn"), seeds=2, steps=10, out=str(tmp_path / "grid")
    )
    order = [(j["algo"], j["seed"]) for j in jobs_for(cfg)]
    assert order == [("ppo", 0), ("dqn", 0), ("ppo", 1), ("dqn", 1)]
    assert [Path(j["run_dir"]).name for j in jobs_for(cfg)][:2] == ["ppo-s0", "dqn-s0"]


def test_summary_pools_successes_with_wilson_and_spreads_over_seeds() -> None:
    def job(algo: str, seed: int, k: int) -> dict[str, Any]:
        return {
            "algo": algo,
            "seed": seed,
            "steps": 100,
            "wall_s": 10.0,
            "steps_per_s": 10.0,
            "eval": {
                "success_rate": k / 10,
                "successes": k,
                "episodes": 10,
                "median_final_distance_m": 0.01,
                "mean_return": -1.0,
            },
        }

    s = summarise([job("ppo", 0, 9), job("ppo", 1, 10), job("ppo", 2, 8)])["ppo"]
    assert s["success_rate_pooled"] == pytest.approx(0.9)
    lo, hi = s["success_rate_pooled_wilson95"]
    assert lo == pytest.approx(0.7438, abs=1e-4) and hi == pytest.approx(0.9654, abs=1e-4)
    assert s["success_rate_mean"] == pytest.approx(0.9)
    lo, hi = s["success_rate_seed_ci95"]  # Student t over 3 seeds, clipped to [0, 1]
    assert lo == pytest.approx(0.9 - 4.303 * 0.1 / 3**0.5, rel=1e-3) and hi == 1.0


def test_bad_grids_fail_before_any_training(tmp_path: Path) -> None:
    out = str(tmp_path / "x")
    with pytest.raises(Sim2RealError, match="unknown algo 'trpo'"):
        CompareConfig(env="reach", algos=("ppo", "trpo"), seeds=1, steps=10, out=out)
    with pytest.raises(Sim2RealError, match="unknown backend 'slurm'; valid: local, ray"):
        CompareConfig(env="reach", algos=("ppo",), seeds=1, steps=10, out=out, backend="slurm")
    with pytest.raises(ConfigError, match="seeds must be an integer >= 1"):
        CompareConfig(env="reach", algos=("ppo",), seeds=0, steps=10, out=out)
    with pytest.raises(ConfigError, match="not in --algos"):
        CompareConfig(
            env="reach", algos=("ppo",), seeds=1, steps=10, out=out, overrides={"sac": ("tau=0.1",)}
        )
    with pytest.raises(ConfigError, match=r"--preset names algorithm\(s\) \['dqn'\]"):
        CompareConfig(
            env="reach", algos=("ppo",), seeds=1, steps=10, out=out, presets={"dqn": "dqn_reach"}
        )
    with pytest.raises(Sim2RealError, match="unknown preset 'ppo_fast'"):
        CompareConfig(
            env="reach", algos=("ppo",), seeds=1, steps=10, out=out, presets={"ppo": "ppo_fast"}
        )
    with pytest.raises(ConfigError, match="--preset 'ppo_reach' must be ALGO:NAME"):
        parse_presets(["ppo_reach"])
    assert parse_presets(["PPO:ppo_default", "dqn:dqn_reach"]) == {
        "ppo": "ppo_default",
        "dqn": "dqn_reach",
    }
    assert parse_overrides(["ppo:n_steps=64", "gamma=0.9"], ("ppo", "a2c")) == {
        "ppo": ("n_steps=64", "gamma=0.9"),
        "a2c": ("gamma=0.9",),
    }
    cfg = CompareConfig(
        env="reach",
        algos=("ppo",),
        seeds=1,
        steps=10,
        out=out,
        overrides={"ppo": ("bogus_param=1",)},
    )
    with pytest.raises(ConfigError, match="unknown ppo hyperparameter"):
        run_compare(cfg)
    assert not (tmp_path / "x" / "runs").exists()


def test_the_report_states_the_steps_a_wall_limit_left_and_the_overrides() -> None:
    from sim2real.compare.report import _budget_text, _overrides_text

    config = {"steps": 1000}
    assert _budget_text(config, [{"steps": 1000}, {"steps": 1024}]) == "for 1000 env steps"
    text = _budget_text(config, [{"steps": 700}, {"steps": 1000}])
    assert "at most 1000 env steps" in text and "700–1,000 steps" in text
    assert _overrides_text({}) == ""
    assert _overrides_text({"ppo": ["max_wall_s=60"], "dqn": []}) == (
        " Overrides (`--set`): ppo: `max_wall_s=60`."
    )
