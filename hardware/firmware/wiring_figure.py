"""Draw the potentiometer mod's wiring for the hardware guide (docs/img/pot-mod-wiring.png).

    python -m hardware.firmware.wiring_figure docs/img/pot-mod-wiring.png

matplotlib is needed only here (it is imported inside ``draw``), so the hardware package still
installs with numpy, pyserial and PyYAML alone.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hardware.firmware.limits import NOMINAL_POT_COUNTS, UNO_ADC_CHANNELS, UNO_PWM_PINS

SERVOS = ("base_yaw", "shoulder", "elbow", "gripper")  # servo_id 0..3 in the shipped specs


def _box(ax: Any, x: float, y: float, w: float, h: float, label: str, colour: str) -> None:
    from matplotlib.patches import FancyBboxPatch

    ax.add_patch(
        FancyBboxPatch(
            (x, y), w, h, boxstyle="round,pad=0.02", fc=colour, ec="black", lw=1.2, zorder=1
        )
    )
    ax.text(x + w / 2, y + h - 0.25, label, ha="center", va="top", fontsize=10, weight="bold")


def _wire(ax: Any, xs: Sequence[float], ys: Sequence[float], colour: str, lw: float = 2.0) -> None:
    ax.plot(xs, ys, color=colour, lw=lw, solid_capstyle="round", zorder=2)


def draw(out: Path) -> Path:
    """Write the figure: one servo opened up in detail, and the four wipers on A0..A3."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(13, 6.2), dpi=110)
    ax.set_xlim(0, 26)
    ax.set_ylim(0, 12.4)
    ax.axis("off")

    # ---- one servo, opened ------------------------------------------------------------------
    _box(ax, 0.5, 3.2, 7.0, 8.2, "MG996R, case opened (servo_id 1: shoulder)", "#eef2f7")
    _box(ax, 1.0, 8.2, 3.0, 2.2, "servo board", "#d5e8d4")
    ax.text(2.5, 8.9, "motor driver\n+ control IC", ha="center", fontsize=8)
    # the potentiometer: a resistor track with a wiper arrow
    ax.add_patch(matplotlib.patches.Rectangle((4.9, 4.5), 0.7, 3.2, fc="#f8cecc", ec="black"))
    ax.annotate("", xy=(5.6, 6.1), xytext=(6.9, 6.1), arrowprops={"arrowstyle": "->", "lw": 2.0})
    ax.text(5.8, 5.2, "feedback pot\n(turns with\nthe horn)", ha="left", va="top", fontsize=8)
    # its three legs: two ends to the board, the wiper to the board (and now out)
    _wire(ax, [5.25, 5.25, 4.0], [7.7, 9.6, 9.6], "#c00000")
    ax.text(4.3, 9.75, "pot end", fontsize=7, color="#c00000")
    _wire(ax, [5.25, 5.25, 3.2, 3.2], [4.5, 3.9, 3.9, 8.2], "#333333")
    ax.text(3.3, 4.05, "pot end (GND)", fontsize=7)
    _wire(ax, [6.9, 6.9, 4.0], [6.1, 8.7, 8.7], "#1f5fbf")
    ax.text(6.2, 8.85, "wiper", fontsize=7, color="#1f5fbf")
    # the one new wire: solder to the wiper, lead it out of the case
    _wire(ax, [6.9, 9.6], [6.1, 6.1], "#1f5fbf", lw=3.0)

    # ---- protection at the analog pin ---------------------------------------------------------
    ax.add_patch(matplotlib.patches.Rectangle((9.6, 5.85), 1.6, 0.5, fc="white", ec="black"))
    ax.text(10.4, 6.5, "4.7 kΩ", ha="center", fontsize=8)
    _wire(ax, [11.2, 13.2, 13.2, 14.2], [6.1, 6.1, 8.55, 8.55], "#1f5fbf", lw=3.0)
    _wire(ax, [12.2, 12.2], [6.1, 5.2], "#1f5fbf")
    ax.plot([11.8, 12.6], [5.2, 5.2], color="black", lw=2)
    ax.plot([11.8, 12.6], [4.95, 4.95], color="black", lw=2)
    _wire(ax, [12.2, 12.2], [4.95, 2.85], "#333333")
    ax.text(10.6, 4.45, "100 nF", fontsize=8)
    ax.text(
        8.2,
        8.2,
        "series resistor + capacitor to GND:\nfilters PWM noise, and limits the\n"
        "current if the wiper passes 5 V",
        fontsize=7.5,
    )
    ax.text(7.8, 5.2, "new wire, soldered\nto the wiper leg", fontsize=8, color="#1f5fbf")

    # ---- the Arduino ----------------------------------------------------------------------------
    _box(ax, 14.2, 3.2, 6.4, 8.2, "Arduino Uno / Nano", "#fff2cc")
    for i, name in enumerate(SERVOS):
        y = 9.6 - 1.1 * i
        ax.text(
            14.4,
            y - 0.05,
            f"A{UNO_ADC_CHANNELS[i]} ← {name} wiper",
            fontsize=8.5,
            color="#1f5fbf" if i == 1 else "black",
        )
        ax.text(18.4, y - 0.05, f"D{UNO_PWM_PINS[i]} → signal", fontsize=8.5)
    ax.text(14.9, 4.5, "GND", fontsize=8.5, weight="bold")
    ax.text(14.4, 3.6, "AREF: 5 V (AVCC)", fontsize=8)

    # ---- supply and the common ground -------------------------------------------------------
    _box(ax, 0.5, 0.2, 7.0, 2.3, "6 V servo supply (≥ 5 A)", "#e1d5e7")
    _wire(ax, [4.0, 4.0, 20.6], [2.5, 2.85, 2.85], "#333333", lw=2.5)
    _wire(ax, [14.6, 14.6], [2.85, 4.6], "#333333", lw=2.5)
    ax.text(8.0, 2.2, "common ground: supply −, servo brown wires, Arduino GND", fontsize=8.5)

    # ---- the numbers ------------------------------------------------------------------------
    ax.text(21.2, 11.0, "What the firmware does", fontsize=10, weight="bold", va="top")
    ax.text(
        21.2,
        10.4,
        "spec: feedback: measured\n"
        "→ limits.h: ARM3_POT_CHANNEL\n"
        "one analogRead per loop,\n"
        "round robin (~0.11 ms each)\n\n"
        "counts → µs on the chip:\n"
        f"nominal {NOMINAL_POT_COUNTS[0]} counts at 500 µs,\n"
        f"{NOMINAL_POT_COUNTS[1]} counts at 2500 µs\n"
        "(measure yours: --pot)\n\n"
        "STATE readings byte:\n"
        "bit i = actuator i measured",
        fontsize=8,
        va="top",
    )
    fig.suptitle(
        "The potentiometer mod: the servo's own position sensor, wired to an analog input",
        fontsize=12,
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, bbox_inches="tight")
    plt.close(fig)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="draw the potentiometer mod's wiring")
    parser.add_argument("out", nargs="?", default="docs/img/pot-mod-wiring.png")
    args = parser.parse_args(argv)
    try:
        print(draw(Path(args.out)))
    except ImportError:
        print("error: the figure needs matplotlib (pip install matplotlib)", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
