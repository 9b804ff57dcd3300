"""Held-out episodes live below evaluate and deploy (``sim2real.held_out``)."""

from __future__ import annotations


def test_the_trainer_and_the_held_out_episodes_share_one_seed_base() -> None:
    """Training seeds stay below it, evaluation and replayed placements start at it: the two
    statements of the value must be one value."""
    from sim2real import held_out
    from sim2real.evaluate import core
    from sim2real.train.config import EVAL_SEED_BASE

    assert held_out.EVAL_SEED_BASE == EVAL_SEED_BASE
    assert core.EvalTarget is held_out.EvalTarget  # evaluate's names are the same objects
    assert core.held_out_placements is held_out.held_out_placements
