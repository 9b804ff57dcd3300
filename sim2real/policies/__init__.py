"""Shipped policies: measured, recommended, exported (ONNX with embedded metadata and the arm
spec's fingerprint), a few hundred kB each. ``sim2real policies`` lists them; every command that
takes a run directory or a policy file also takes a shipped policy's name.

Each policy is ``<name>.onnx`` plus a card ``<name>.json``: what it is for, how it was trained
and what it measured (``bench/ship_policies.py`` writes both). A policy that may be fine-tuned
(``sim2real adapt``) also ships its SB3 checkpoint, named in the card's ``checkpoint``:
``<name>.zip`` (actor, critic, optimiser) and ``<name>.train.json`` (the run's config and its
observation-normalisation statistics as numbers).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sim2real.errors import RunDirError

SHIPPED_DIR = Path(__file__).parent


@dataclass(frozen=True)
class ShippedPolicy:
    name: str
    path: Path  # the exported policy file
    task: str
    env_id: str
    algo: str
    summary: str
    figures: dict[str, Any] = field(default_factory=dict)
    trained: dict[str, Any] = field(default_factory=dict)
    checkpoint: tuple[Path, Path] | None = None  # (SB3 .zip, .train.json) when fine-tunable


def shipped() -> dict[str, ShippedPolicy]:
    """Name → policy, for every card whose policy file is present."""
    out: dict[str, ShippedPolicy] = {}
    for card in sorted(SHIPPED_DIR.glob("*.json")):
        if "." in card.stem:  # <name>.train.json beside a card, not a card
            continue
        try:
            d = json.loads(card.read_text())
            path = SHIPPED_DIR / str(d["file"])
            if not path.is_file():
                continue
            ckpt = d.get("checkpoint")
            checkpoint = None
            if ckpt is not None:
                checkpoint = (SHIPPED_DIR / str(ckpt["model"]), SHIPPED_DIR / str(ckpt["stats"]))
                missing = [p.name for p in checkpoint if not p.is_file()]
                if missing:
                    raise ValueError(f"its checkpoint files {missing} are missing")
            out[card.stem] = ShippedPolicy(
                name=card.stem,
                path=path,
                task=str(d["task"]),
                env_id=str(d["env_id"]),
                algo=str(d["algo"]),
                summary=str(d.get("summary", "")),
                figures=dict(d.get("figures", {})),
                trained=dict(d.get("trained", {})),
                checkpoint=checkpoint,
            )
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise RunDirError(f"shipped policy card {card.name!r} is unreadable: {exc}") from None
    return out


def resolve_policy(ref: str | Path) -> Path:
    """A run directory or exported file as given, else a shipped policy's file by name."""
    p = Path(ref)
    if p.exists():
        return p
    text = str(ref)
    ships = shipped()
    if text in ships:
        return ships[text].path
    raise RunDirError(
        f"policy {text!r} does not exist: no run directory, policy file or shipped policy of "
        f"that name; shipped policies: {sorted(ships) or 'none'}"
    )
