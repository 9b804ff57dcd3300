"""Run-time noise for the sensor and servo models the envs run every step (not DR: DR only
samples how large the noise is)."""

from __future__ import annotations

import numpy as np


class NoiseBuffer:
    """Standard-normal draws in blocks: one RNG call per ``block`` steps instead of per step
    (a per-step call costs more than the arithmetic it feeds). ``clear`` at episode reset keeps
    same-seed rollouts identical."""

    def __init__(self, dim: int, block: int = 64) -> None:
        self.dim, self.block = dim, block
        self._buf = np.zeros((0, dim))
        self._i = 0

    def clear(self) -> None:
        self._buf = np.zeros((0, self.dim))
        self._i = 0

    def take(self, rng: np.random.Generator) -> np.ndarray:
        if self._i >= len(self._buf):
            self._buf = rng.standard_normal((self.block, self.dim))
            self._i = 0
        row = self._buf[self._i]
        self._i += 1
        return row
