"""Calibration report: Markdown (always) and a PNG figure (when matplotlib is installed).

Per camera the figure shows the residual scatter (detected − projected corners), the per-view
RMS bars (rejected views in red) and the corner coverage heatmap. matplotlib is an *optional*
dependency of this module only: it is imported inside :func:`render_png`, so ``calibration``
itself imports with numpy, OpenCV and filterpy alone.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from datetime import datetime, timezone

import numpy as np

from calibration.intrinsics import IntrinsicsResult, ViewReport
from calibration.stereo import StereoResult

PNG_NAME = "report.png"


def _fmt(value: float | None, digits: int = 3) -> str:
    if value is None or math.isnan(value):
        return "—"
    return f"{value:.{digits}f}"


def _camera_table(results: Sequence[IntrinsicsResult]) -> list[str]:
    lines = [
        "| camera | fx (px) | fy (px) | cx (px) | cy (px) | RMS (px) | views used | rejected |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        c, s = r.camera, r.std
        lines.append(
            f"| {c.name} | {c.fx:.2f} ± {s.get('fx', 0):.2f} | {c.fy:.2f} ± {s.get('fy', 0):.2f} "
            f"| {c.cx:.2f} ± {s.get('cx', 0):.2f} | {c.cy:.2f} ± {s.get('cy', 0):.2f} "
            f"| {r.rms_px:.3f} | {r.views_used} | {r.views_rejected} |"
        )
    lines.append("")
    lines.append("Distortion (k1, k2, p1, p2, k3, …) with ±σ:")
    lines.append("")
    for r in results:
        names = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")
        terms = [
            f"{n} = {v:.5f} ± {r.std.get(n, 0.0):.5f}"
            for n, v in zip(names, r.camera.dist, strict=False)
        ]
        lines.append(f"- {r.camera.name}: " + ", ".join(terms))
    return lines


def _cross_lines(results: Sequence[IntrinsicsResult]) -> list[str]:
    lines = ["## Odd/even cross-validation", ""]
    for r in results:
        cv = r.cross_validation
        if not cv:
            lines.append(f"- {r.camera.name}: too few views to split")
            continue
        lines.append(
            f"- {r.camera.name}: |Δfx| = {cv['fx_px']:.2f} px ({cv['fx_pct']:.2f}%), "
            f"|Δfy| = {cv['fy_px']:.2f} px, |Δcx| = {cv['cx_px']:.2f} px, "
            f"|Δcy| = {cv['cy_px']:.2f} px; held-out RMS {cv['heldout_rms_px']:.3f} px"
        )
    return lines


def _coverage_lines(results: Sequence[IntrinsicsResult]) -> list[str]:
    lines = ["## Coverage", ""]
    shades = " .:-=+*#%@"
    for r in results:
        cov = r.coverage
        top = max(int(cov.max()), 1)
        lines.append(
            f"{r.camera.name}: {100 * r.coverage_fraction:.0f}% of the cells hold corners "
            "(darker = more corners)"
        )
        lines.append("")
        lines.append("```")
        for row in cov:
            lines.append("".join(shades[min(9, math.ceil(9 * v / top))] * 2 for v in row))
        lines.append("```")
        lines.append("")
    return lines


def _view_lines(title: str, views: Sequence[ViewReport]) -> list[str]:
    lines = [f"## {title}", "", "| view | RMS (px) | used | note |", "|---|---|---|---|"]
    for v in views:
        lines.append(f"| {v.name} | {_fmt(v.rms_px)} | {'yes' if v.used else 'no'} | {v.reason} |")
    return lines


def _warning_lines(warnings: Sequence[str]) -> list[str]:
    return ["## Warnings", ""] + ([f"- ⚠ {w}" for w in warnings] if warnings else ["None."])


def markdown_report(
    result: IntrinsicsResult | StereoResult, board: str, with_png: bool = True
) -> str:
    """The Markdown report of a mono or stereo calibration."""
    now = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    if isinstance(result, StereoResult):
        cams = [result.left, result.right]
        title = "Stereo calibration report"
    else:
        cams = [result]
        title = "Camera calibration report"
    lines = [f"# {title}", "", f"Board `{board}`, {now}.", ""]
    if with_png:
        lines += [f"![residuals, per-view errors and coverage]({PNG_NAME})", ""]
    lines += ["## Intrinsics", ""] + _camera_table(cams) + [""]
    if isinstance(result, StereoResult):
        rig = result.rig
        angle = math.degrees(math.acos(np.clip((np.trace(rig.R) - 1) / 2, -1, 1)))
        cv = result.cross_validation
        lines += [
            "## Stereo",
            "",
            f"- RMS {result.rms_px:.3f} px over {result.views_used} pairs "
            f"({result.views_rejected} rejected)",
            f"- baseline {rig.baseline:.5g} (board units); T = "
            f"[{', '.join(f'{v:.5g}' for v in rig.T)}]; rotation between the cameras "
            f"{angle:.2f}°",
            f"- epipolar error: RMS {result.epipolar_rms_px:.3f} px, max "
            f"{result.epipolar_max_px:.3f} px",
        ]
        if cv:
            lines.append(
                f"- odd/even pairs: baseline {cv['baseline_even']:.5g} vs "
                f"{cv['baseline_odd']:.5g} ({cv['baseline_pct']:.2f}%)"
            )
        lines.append("")
    lines += _cross_lines(cams) + [""] + _coverage_lines(cams)
    warnings = result.all_warnings if isinstance(result, StereoResult) else result.warnings
    lines += _warning_lines(warnings) + [""]
    for cam in cams:
        lines += _view_lines(f"Views: {cam.camera.name}", cam.views) + [""]
    if isinstance(result, StereoResult):
        lines += _view_lines("Stereo pairs", result.pairs) + [""]
    return "\n".join(lines)


def render_png(result: IntrinsicsResult | StereoResult) -> bytes | None:
    """The report figure as PNG bytes; ``None`` when matplotlib is not installed."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    stereo = isinstance(result, StereoResult)
    cams = [result.left, result.right] if isinstance(result, StereoResult) else [result]
    n_rows = len(cams) + (1 if stereo else 0)
    fig = plt.figure(figsize=(15, 4.2 * n_rows))
    grid = fig.add_gridspec(n_rows, 3)
    axes = [[fig.add_subplot(grid[r, c]) for c in range(3)] for r in range(len(cams))]
    if isinstance(result, StereoResult):
        ax = fig.add_subplot(grid[len(cams), :])
        pairs = [p for p in result.pairs if p.rms_px is not None]
        ax.bar(
            range(len(pairs)),
            [p.rms_px or 0.0 for p in pairs],
            color=["tab:blue" if p.used else "tab:red" for p in pairs],
        )
        ax.axhline(result.rms_px, color="k", lw=0.8, ls="--", label="stereo RMS")
        ax.set_xticks(range(len(pairs)))
        ax.set_xticklabels([p.name for p in pairs], rotation=90, fontsize=6)
        ax.set_title("stereo: per-pair RMS (red: rejected)")
        ax.set_ylabel("RMS (px)")
        ax.legend(loc="upper right", fontsize=7)
    for row, cam in zip(axes, cams, strict=True):
        res = cam.residuals_px
        ax = row[0]
        ax.scatter(res[:, 0], res[:, 1], s=3, alpha=0.5)
        lim = max(float(np.abs(res).max()) * 1.1, 0.1)
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_aspect("equal")
        ax.axhline(0, color="grey", lw=0.5)
        ax.axvline(0, color="grey", lw=0.5)
        ax.set_title(f"{cam.camera.name}: residuals (RMS {cam.rms_px:.3f} px)")
        ax.set_xlabel("x (px)")
        ax.set_ylabel("y (px)")
        ax = row[1]
        views = [v for v in cam.views if v.rms_px is not None]
        colours = ["tab:blue" if v.used else "tab:red" for v in views]
        ax.bar(range(len(views)), [v.rms_px or 0.0 for v in views], color=colours)
        ax.axhline(cam.rms_px, color="k", lw=0.8, ls="--", label="overall RMS")
        ax.set_xticks(range(len(views)))
        ax.set_xticklabels([v.name for v in views], rotation=90, fontsize=6)
        ax.set_title(f"{cam.camera.name}: per-view RMS (red: rejected)")
        ax.set_ylabel("RMS (px)")
        ax.legend(loc="upper right", fontsize=7)
        ax = row[2]
        im = ax.imshow(cam.coverage, cmap="viridis", interpolation="nearest")
        ax.set_title(f"{cam.camera.name}: corner coverage ({100 * cam.coverage_fraction:.0f}%)")
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04, label="corners per cell")
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90)
    plt.close(fig)
    return buffer.getvalue()
