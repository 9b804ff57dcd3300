"""The learner's defaults, shared by ``sim2real finetune``, its options and the proxy bench (no
imports: the CLI's parser reads them at start-up).

Measured with ``bench/finetune_proxy.py`` (the learner's own code on the training env forced to
the hard plant, faster than real time; docs/studies/learning-on-the-arm.md, "Learning on the arm (issue 21)"), DDPG
reach, 7,000 env steps (what 15 arm minutes hold): without relabelling no setting left the
zero-shot interval (0.10-0.13 -> 0.18-0.26); hindsight relabelling took it to 0.74-0.76 (share
0.5-0.8) and, with exploration noise 0.2 instead of the sources' 0.1, to 0.86. utd 2 and 4, TD3,
noise 0.3 and a 2,000-step critic warm-up did no better.
"""

from __future__ import annotations

LEARNER_DEFAULTS: dict[str, float | int] = {
    "utd": 1.0,  # gradient steps per online transition
    "learning_starts": 200,  # online transitions before the first gradient step
    "actor_starts": 0,  # online transitions of critic-only updates before the actor's first
    # share of every online batch given a goal reached later in its episode (tasks with goals)
    "relabel": 0.8,
    "noise_std": 0.2,  # DDPG/TD3 exploration std on the normalised actions (sources train at 0.1)
}

# how the actor learns on the arm (``--actor-update``), and why one would choose each
ACTOR_UPDATES: dict[str, str] = {
    "critic": "the algorithm's own update: follow the critic's action gradient",
    "success": "regress on the actions of the arm's own successful episodes (filtered "
    "imitation): a critic fitted on minutes of one arm cannot pull the actor off the data",
    "advantage": "regress on every action the arm took, weighted by the critic's advantage "
    "(AWAC): the critic chooses among the data, it cannot lead the actor away from it",
}
