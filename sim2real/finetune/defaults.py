"""The learner's defaults, shared by ``sim2real finetune``, its options and the proxy bench (no
imports: the CLI's parser reads them at start-up).

Measured with ``bench/finetune_proxy.py`` (the learner's own code on the training env forced to
the plant, faster than real time) and confirmed on the mock arm: BENCHMARKS.md "Learning on the
arm (issue 21)".
"""

from __future__ import annotations

LEARNER_DEFAULTS: dict[str, float | int] = {
    "utd": 1.0,  # gradient steps per online transition
    "learning_starts": 200,  # online transitions before the first gradient step
    "actor_starts": 0,  # online transitions of critic-only updates before the actor's first
}
