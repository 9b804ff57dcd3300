"""The learner's defaults, shared by ``sim2real finetune``, its options and the proxy bench (no
imports: the CLI's parser reads them at start-up).

Measured with ``bench/finetune_proxy.py`` (the learner's own code on the training env forced to
the hard plant, faster than real time; BENCHMARKS.md "Learning on the arm (issue 21)"): utd 4
drove the actor to 0 % success, a 2,000-step critic warm-up did no better than none, and no
setting tried reached the target within 18,000 steps, so these stay until one does.
"""

from __future__ import annotations

LEARNER_DEFAULTS: dict[str, float | int] = {
    "utd": 1.0,  # gradient steps per online transition
    "learning_starts": 200,  # online transitions before the first gradient step
    "actor_starts": 0,  # online transitions of critic-only updates before the actor's first
    # share of every online batch given a goal reached later in its episode (tasks with goals)
    "relabel": 0.8,
}
