"""``sim2real view``: what the policy saw and did, in Rerun, for debugging by looking.

A run (a deploy log, a finetune or adapt folder, a LeRobot dataset from ``evaluate`` or
``deploy --record-dataset``) is read into one ``ViewRun`` (``sources``): per-period columns in the
deploy log's vocabulary, the episodes' outcomes, events, and, where the run has them, camera frames.
``record`` turns runs into one Rerun recording (each run its own entity subtree, on shared
timelines); ``live`` streams a running deploy's periods to a viewer from a worker thread, so the
control loop never waits for it. Only ``record`` and ``live`` import Rerun (the ``view`` extra).
"""

from __future__ import annotations

from sim2real.view.sources import SOURCES, ViewRun, load_run

__all__ = ["SOURCES", "ViewRun", "load_run"]
