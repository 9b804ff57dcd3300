"""Where a deploy's objects come from: the loop's own draws, or the policy's held-out evaluation
episodes replayed (``--placements held-out``), so that a deploy and ``sim2real evaluate --dr
none``, or two backends, are compared on the same placements."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from sim2real.errors import ConfigError, UnknownNameError

Placements = tuple[Mapping[str, Any], ...]


def _loop(policy: str, episodes: int) -> Placements:
    return ()  # the loop draws its own (``LoopConfig.seed``)


def _held_out(policy: str, episodes: int) -> Placements:
    """``evaluate``'s held-out episodes under DR ``none`` (the nominal model: what the sim and
    mock worlds place objects in); needs the simulator installed."""
    from sim2real.evaluate.core import EvalTarget, held_out_placements
    from sim2real.policies import resolve_policy

    return tuple(held_out_placements(EvalTarget.load(resolve_policy(policy)), episodes))


PLACEMENT_SOURCES: dict[str, Callable[[str, int], Placements]] = {
    "loop": _loop,
    "held-out": _held_out,
}


def placements(source: str, policy: str, episodes: int) -> Placements:
    """The placements ``LoopConfig.placements`` replays for ``source`` (empty: the loop draws)."""
    check_source(source, "")
    return PLACEMENT_SOURCES[source](policy, episodes)


def check_source(source: str, backend: str) -> None:
    """Replayed placements need a world that places objects: on a real arm a person does."""
    if source not in PLACEMENT_SOURCES:
        raise UnknownNameError("placement source", source, PLACEMENT_SOURCES)
    if source != "loop" and backend == "serial":
        raise ConfigError(f"--placements {source}: on a real arm a person places the objects")
