"""Compare algorithms under identical conditions: every (algo, seed) gets the same env, DR,
budget and held-out evaluation seeds; the report shows learning curves with confidence bands,
the final success table and each algorithm's own diagnostics."""

from __future__ import annotations

from sim2real.compare.runner import CompareConfig, run_compare

__all__ = ["CompareConfig", "run_compare"]
