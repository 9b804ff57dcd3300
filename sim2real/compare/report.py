"""The comparison report: ``results.json``, ``report.md`` and the PNGs it shows."""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.evaluate.stats import mean_ci95, wilson_interval
from sim2real.train.atomic import atomic_write, atomic_write_json, atomic_write_text

LEARNING_PANELS: tuple[tuple[str, str], ...] = (
    ("success_rate", "training success rate"),
    ("return", "episode return"),
    ("length", "episode length (steps)"),
)


def _band(
    per_seed: Sequence[Sequence[float | None]],
) -> tuple[list[float], list[float], list[float]]:
    """Mean and 95% t-interval across seeds, bin by bin (empty bins stay NaN)."""
    arr = np.array([[math.nan if v is None else v for v in s] for s in per_seed], dtype=float)
    mean, lo, hi = [], [], []
    for col in arr.T:
        m, a, b = mean_ci95(col.tolist())
        mean.append(m)
        lo.append(a)
        hi.append(b)
    return mean, lo, hi


def summarise(jobs: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per algorithm: success across seeds (mean, t-interval), pooled Wilson, speed."""
    out: dict[str, dict[str, Any]] = {}
    for algo in dict.fromkeys(j["algo"] for j in jobs):
        js = [j for j in jobs if j["algo"] == algo]
        rates = [j["eval"]["success_rate"] for j in js]
        k = sum(j["eval"]["successes"] for j in js)
        n = sum(j["eval"]["episodes"] for j in js)
        m, lo, hi = mean_ci95(rates)
        out[algo] = {
            "seeds": [j["seed"] for j in js],
            "success_rate_per_seed": rates,
            "success_rate_mean": m,
            "success_rate_seed_ci95": [max(0.0, lo), min(1.0, hi)],  # a rate stays in [0, 1]
            "success_rate_pooled": k / n if n else math.nan,
            "success_rate_pooled_wilson95": list(wilson_interval(k, n)),
            "median_final_distance_m": float(
                np.median([j["eval"]["median_final_distance_m"] for j in js])
            ),
            "mean_return": float(np.mean([j["eval"]["mean_return"] for j in js])),
            "wall_s_mean": float(np.mean([j["wall_s"] for j in js])),
            "steps_per_s_mean": float(np.mean([j["steps_per_s"] for j in js])),
            "steps": int(max(j["steps"] for j in js)),
        }
    return out


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _steps_axis(ax: Any) -> None:
    """Env steps in k/M: raw 6-digit tick labels run into each other on a 4-inch panel."""
    from matplotlib.ticker import EngFormatter

    ax.xaxis.set_major_formatter(EngFormatter(sep=""))
    ax.set_xlabel("env steps")


def _save(fig: Any, path: Path) -> Path:
    atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=100, bbox_inches="tight"))
    _plt().close(fig)
    return path


def plot_learning(jobs: Sequence[Mapping[str, Any]], path: Path, title: str) -> Path:
    plt = _plt()
    fig, axes = plt.subplots(1, len(LEARNING_PANELS), figsize=(15, 4))
    for algo in dict.fromkeys(j["algo"] for j in jobs):
        js = [j for j in jobs if j["algo"] == algo]
        x = js[0]["curves"]["bin_centres"]
        for ax, (key, label) in zip(axes, LEARNING_PANELS, strict=True):
            mean, lo, hi = _band([j["curves"]["learning"][key] for j in js])
            if key == "success_rate":
                lo, hi = list(np.clip(lo, 0.0, 1.0)), list(np.clip(hi, 0.0, 1.0))
            (line,) = ax.plot(x, mean, label=f"{algo} ({len(js)} seeds)")
            ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.2, linewidth=0)
            _steps_axis(ax)
            ax.set_ylabel(label)
    axes[0].set_ylim(-0.02, 1.02)
    axes[0].legend(loc="best")
    fig.suptitle(f"{title} — mean and 95% interval across seeds")
    return _save(fig, path)


def plot_final(summary: Mapping[str, Mapping[str, Any]], path: Path, title: str) -> Path:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(1.6 * len(summary) + 2, 4))
    for i, s in enumerate(summary.values()):
        p = s["success_rate_pooled"]
        lo, hi = s["success_rate_pooled_wilson95"]
        ax.bar(i, p, color=f"C{i}", alpha=0.6)
        ax.errorbar(i, p, yerr=[[p - lo], [hi - p]], color="k", capsize=4)
        ax.scatter(
            [i] * len(s["success_rate_per_seed"]), s["success_rate_per_seed"], color="k", s=12
        )
    ax.set_xticks(range(len(summary)), list(summary))
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("held-out success (pooled, Wilson 95%; dots: seeds)")
    ax.set_title(title)
    return _save(fig, path)


def plot_diagnostics(jobs: Sequence[Mapping[str, Any]], algo: str, path: Path) -> Path | None:
    js = [j for j in jobs if j["algo"] == algo]
    keys = [
        k
        for k in js[0]["curves"]["diagnostics"]
        if any(v is not None for j in js for v in j["curves"]["diagnostics"][k])
    ]
    if not keys:
        return None
    plt = _plt()
    cols = min(3, len(keys))
    rows = math.ceil(len(keys) / cols)
    fig, axes = plt.subplots(
        rows, cols, figsize=(5 * cols, 3.3 * rows), squeeze=False, layout="constrained"
    )
    x = js[0]["curves"]["bin_centres"]
    for ax, key in zip(axes.flat, keys, strict=False):
        mean, lo, hi = _band([j["curves"]["diagnostics"][key] for j in js])
        ax.plot(x, mean)
        ax.fill_between(x, lo, hi, alpha=0.25, linewidth=0)
        ax.set_title(key)
        _steps_axis(ax)
    for ax in list(axes.flat)[len(keys) :]:
        ax.axis("off")
    fig.suptitle(f"{algo} diagnostics — mean and 95% interval across seeds")
    return _save(fig, path)


def _pct(x: float) -> str:
    return "n/a" if not math.isfinite(x) else f"{100 * x:.1f}%"


def _relative(path: str, out: Path) -> str:
    """``path`` relative to the report folder when inside it: a report is committed and moved
    as a folder, so it must not name the machine it ran on."""
    try:
        return Path(path).resolve().relative_to(out.resolve()).as_posix()
    except ValueError:
        return path


def _portable(job: Mapping[str, Any], out: Path) -> dict[str, Any]:
    j = dict(job)
    j["run_dir"] = _relative(str(j["run_dir"]), out)
    if isinstance(j.get("eval"), Mapping) and "policy" in j["eval"]:
        j["eval"] = {**j["eval"], "policy": _relative(str(j["eval"]["policy"]), out)}
    return j


def _budget_text(config: Mapping[str, Any], jobs: Sequence[Mapping[str, Any]]) -> str:
    """The steps the runs actually trained: a wall-clock limit (``--set max_wall_s=...``) can
    stop a run before ``--steps``, and the report must not claim the budget it did not get."""
    steps = int(config["steps"])
    done = [int(j["steps"]) for j in jobs]
    if not done or min(done) >= steps:
        return f"for {steps} env steps"
    return (
        f"for at most {steps} env steps; a wall-clock limit stopped runs after "
        f"{min(done):,}–{max(done):,} steps (the runs table gives each)"
    )


def _overrides_text(overrides: Mapping[str, Sequence[str]]) -> str:
    """The ``--set`` overrides on top of the presets, per algorithm (empty when none)."""
    named = "; ".join(f"{a}: `{' '.join(v)}`" for a, v in sorted(overrides.items()) if v)
    return f" Overrides (`--set`): {named}." if named else ""


def _presets_text(presets: dict[str, str]) -> str:
    """Which hyperparameter presets the runs used, for the report's first paragraph."""
    if not presets:
        return "its shipped preset"
    named = ", ".join(f"{a}: `{p}`" for a, p in sorted(presets.items()))
    return f"its shipped preset ({named}; the others their own)"


def write_report(
    out: Path,
    config: Mapping[str, Any],
    jobs: Sequence[Mapping[str, Any]],
    versions: Mapping[str, str],
) -> dict[str, Path]:
    out.mkdir(parents=True, exist_ok=True)
    jobs = [_portable(j, out) for j in jobs]
    summary = summarise(jobs)
    stopped = any(int(j["steps"]) < int(config["steps"]) for j in jobs)
    budget = f"{'≤ ' if stopped else ''}{config['steps']} steps"
    title = f"{config['env_id']}, DR {config['dr']}, {budget}"
    files: dict[str, Path] = {
        "learning_curves": plot_learning(jobs, out / "learning_curves.png", title),
        "final_success": plot_final(summary, out / "final_success.png", title),
    }
    for algo in summary:
        p = plot_diagnostics(jobs, algo, out / f"diagnostics_{algo}.png")
        if p is not None:
            files[f"diagnostics_{algo}"] = p
    created = dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")
    results = {
        "config": dict(config),
        "summary": summary,
        "jobs": list(jobs),
        "versions": dict(versions),
        "created_utc": created,
    }
    files["results"] = atomic_write_json(out / "results.json", results)
    lines = [
        f"# Algorithm comparison: {config['env_id']}",
        "",
        f"Created {created} with backend `{config['backend']}`. Every (algorithm, seed) trained "
        f"{_budget_text(config, jobs)} under DR preset `{config['dr']}` with "
        f"{_presets_text(config.get('presets') or {})}, then ran {config['eval_episodes']} "
        "deterministic episodes on held-out seeds (the same seeds for every run)."
        + _overrides_text(config.get("overrides") or {}),
        "",
        "## Final success (held-out episodes)",
        "",
        "| algo | seeds | success, mean across seeds [95% t] | pooled success [Wilson 95%] "
        "| median final distance | wall time | steps/s |",
        "|---|---|---|---|---|---|---|",
    ]
    for algo, s in summary.items():
        lo, hi = s["success_rate_seed_ci95"]
        plo, phi = s["success_rate_pooled_wilson95"]
        lines.append(
            f"| {algo} | {len(s['seeds'])} | {_pct(s['success_rate_mean'])} "
            f"[{_pct(lo)}, {_pct(hi)}] | {_pct(s['success_rate_pooled'])} "
            f"[{_pct(plo)}, {_pct(phi)}] | {1000 * s['median_final_distance_m']:.1f} mm "
            f"| {s['wall_s_mean']:.0f} s | {s['steps_per_s_mean']:.0f} |"
        )
    lines += [
        "",
        "Wall time and steps/s include gradient updates and depend on machine load; compare them "
        "within one report.",
        "",
        "## Learning curves",
        "",
        "![learning curves](learning_curves.png)",
        "",
        "![final success](final_success.png)",
        "",
        "## Diagnostics",
        "",
    ]
    for algo in summary:
        if f"diagnostics_{algo}" in files:
            lines += [f"### {algo}", "", f"![{algo} diagnostics](diagnostics_{algo}.png)", ""]
    lines += ["## Runs", "", "| algo | seed | success | steps | run dir |", "|---|---|---|---|---|"]
    for j in jobs:
        lines.append(
            f"| {j['algo']} | {j['seed']} | {_pct(j['eval']['success_rate'])} | {j['steps']} "
            f"| `{j['run_dir']}` |"
        )
    files["report"] = atomic_write_text(out / "report.md", "\n".join(lines) + "\n")
    return files
