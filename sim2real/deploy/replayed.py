"""Where a deploy's objects come from: the loop's own draws, or the policy's held-out evaluation
episodes replayed (``--placements held-out``), so that a deploy and ``sim2real evaluate --dr
none``, or two backends, are compared on the same placements."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from sim2real.errors import ConfigError, UnknownNameError

if TYPE_CHECKING:
    from sim2real.held_out import EvalTarget

Placements = tuple[Mapping[str, Any], ...]
IN_VIEW_POOL = 3  # held-out episodes looked at per one kept, at most (trace keeps ~86 %)


def _loop(policy: str, episodes: int) -> Placements:
    return ()  # the loop draws its own (``LoopConfig.seed``)


def _held_out(policy: str, episodes: int) -> Placements:
    """``evaluate``'s held-out episodes under DR ``none`` (the nominal model: what the sim and
    mock worlds place objects in) that the rig can see; needs the simulator installed."""
    from sim2real.held_out import EvalTarget
    from sim2real.policies import resolve_policy

    return tuple(held_out_in_view(EvalTarget.load(resolve_policy(policy)), episodes)[1])


def held_out_in_view(
    target: EvalTarget, episodes: int
) -> tuple[list[int], list[dict[str, np.ndarray]]]:
    """The seeds and objects of the first ``episodes`` held-out episodes a deploy can run. For a
    task placed in view (trace), those whose objects the rig's cameras find from the home pose
    (``placement.RigSight``, the check the loop's own draws pass: some env seams end under the
    arm's base, and the same seam replayed would never start); for the others, the first
    ``episodes``. ``evaluate`` on these seeds is then the paired figure."""
    from sim2real.deploy.placement import RigSight
    from sim2real.deploy.policy_io import policy_io
    from sim2real.held_out import held_out_placements

    io = policy_io(target.spec, target.policy.meta)
    contract = io.contract
    if not contract.placed_in_view:
        return target.held_out_seeds(episodes), held_out_placements(target, episodes)
    pool = IN_VIEW_POOL * episodes
    seeds, drawn = target.held_out_seeds(pool), held_out_placements(target, pool)
    sight = RigSight.for_task(target.spec, io.task, contract.objects)
    kept: list[tuple[int, dict[str, np.ndarray]]] = []
    try:
        for seed, placement in zip(seeds, drawn, strict=True):
            if sight.unseen(placement) is None:
                kept.append((seed, placement))
                if len(kept) == episodes:
                    return [k[0] for k in kept], [k[1] for k in kept]
    finally:
        sight.close()
    raise ConfigError(
        f"only {len(kept)} of {pool} held-out placements are in the rig's view; ask for fewer "
        f"than {episodes} episodes"
    )


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
