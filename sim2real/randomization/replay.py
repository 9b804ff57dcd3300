"""One episode's DR draws in a few RNG calls, handed to the category samplers in order.

A reset samples six categories through about 35 small ``Generator`` calls, each costing more in
call overhead than in arithmetic. The samplers draw a fixed sequence for a given preset and
model (no draw depends on a drawn value), so that sequence is recorded once; per episode, each run
of consecutive uniform draws becomes one ``rng.random(n)`` and each normal draw stays its own
call, in the same order. ``Generator.uniform(low, high)`` is ``low + (high - low) * u`` with ``u``
the stream's next double, exactly what ``random`` yields, so the samplers receive the same values,
bit for bit, and the generator ends in the same state (``tests/sim2real/randomization``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from sim2real.errors import ConfigError

# (kind, size, low, high): "u" a uniform draw, "n" a standard-normal one (bounds NaN); size as
# the sampler passed it.
Call = tuple[str, Any, float, float]


def _count(size: Any) -> int:
    if size is None:
        return 1
    if isinstance(size, tuple):
        return math.prod(size)
    return int(size)


class _Recorder:
    """Passes draws through to a real generator and notes each call; anything else is refused,
    so a sampler that needs another kind of draw runs on the reference path."""

    def __init__(self, rng: np.random.Generator) -> None:
        self._rng = rng
        self.calls: list[Call] = []

    def uniform(self, low: Any = 0.0, high: Any = 1.0, size: Any = None) -> Any:
        if np.ndim(low) or np.ndim(high):
            raise ConfigError("replayed DR draws take scalar bounds only")
        self.calls.append(("u", size, float(low), float(high)))
        return self._rng.uniform(low, high, size)

    def standard_normal(self, size: Any = None) -> Any:
        self.calls.append(("n", size, math.nan, math.nan))
        return self._rng.standard_normal(size)


class DrawPlan:
    """The recorded call sequence, grouped into the RNG calls one episode makes."""

    def __init__(self, calls: Sequence[Call]) -> None:
        self.calls = tuple(calls)
        # segments: ("u", (low, span) per double) or ("n", size); per call: (kind, size, low,
        # high, segment, offset)
        segments: list[tuple[str, Any]] = []
        where: list[tuple[str, Any, float, float, int, int]] = []
        for kind, size, low, high in self.calls:
            if kind == "u":
                if not segments or segments[-1][0] != "u":
                    segments.append(("u", []))
                bounds = segments[-1][1]
                where.append((kind, size, low, high, len(segments) - 1, len(bounds)))
                bounds.extend([(low, high - low)] * _count(size))
            else:
                segments.append(("n", size))
                where.append((kind, size, low, high, len(segments) - 1, 0))
        self.segments = tuple(
            (k, np.array(v, dtype=float).T.copy() if k == "u" else v) for k, v in segments
        )
        self.where = tuple(where)
        self.n_calls = len(where)

    @classmethod
    def record(cls, samplers: Sequence[Callable[[Any], Any]]) -> tuple[DrawPlan, list[int]]:
        """Run each ``sample(rng)`` once, in order, on a throwaway generator and keep their
        calls; also where each sampler's calls start (and, last, how many there are)."""
        rec = _Recorder(np.random.default_rng(0))
        starts = []
        for sample in samplers:
            starts.append(len(rec.calls))
            sample(rec)
        starts.append(len(rec.calls))
        return cls(rec.calls), starts

    def replayer(self, rng: np.random.Generator) -> Replay:
        """Make this episode's RNG calls now, in the recorded order; each uniform block is
        scaled to its calls' bounds in one operation (``low + span * u``, numpy's own
        arithmetic for ``uniform``)."""
        blocks: list[Any] = []
        for kind, v in self.segments:
            if kind == "u":
                values = v[0] + v[1] * rng.random(v.shape[1])
                blocks.append((values, values.tolist()))
            else:
                blocks.append(rng.standard_normal(v))
        return Replay(self, blocks)


class Replay:
    """Stands in for the generator while the samplers run: hands out the pre-drawn values in
    the recorded order and checks each call against the recording."""

    def __init__(self, plan: DrawPlan, blocks: list[Any]) -> None:
        self._where = plan.where
        self._n = plan.n_calls
        self._blocks = blocks
        self._i = 0

    def _mismatch(self, i: int, kind: str, size: Any) -> RuntimeError:
        if i >= self._n:
            return RuntimeError(f"DR samplers made more draws than recorded ({self._n})")
        k, s, low, high = self._where[i][:4]
        return RuntimeError(
            f"DR draw {i} is {kind}{size!r}, recorded {k}{s!r} on [{low}, {high}]: a sampler's "
            "draws must not depend on drawn values"
        )

    @property
    def at(self) -> int:
        """The next recorded call."""
        return self._i

    def seek(self, i: int) -> None:
        """Go on from recorded call ``i`` (a sampler whose draws were taken by ``value``)."""
        self._i = i

    def value(self, i: int) -> Any:
        """Recorded uniform call ``i``'s value, as ``uniform`` would return it, unchecked: for
        callers that matched their draws to the recording once, up front."""
        _, size, _, _, seg, off = self._where[i]
        values, flat = self._blocks[seg]
        if size is None:
            return flat[off]
        if isinstance(size, tuple):
            return values[off : off + math.prod(size)].reshape(size)
        return values[off : off + size]

    def uniform(self, low: float = 0.0, high: float = 1.0, size: Any = None) -> Any:
        i = self._i
        if i >= self._n:
            raise self._mismatch(i, "u", size)
        k, s, rl, rh = self._where[i][:4]
        if k != "u" or s != size or rl != low or rh != high:
            raise self._mismatch(i, "u", size)
        self._i = i + 1
        return self.value(i)

    def standard_normal(self, size: Any = None) -> Any:
        i = self._i
        if i >= self._n or self._where[i][0] != "n" or self._where[i][1] != size:
            raise self._mismatch(i, "n", size)
        self._i = i + 1
        return self._blocks[self._where[i][4]]

    def done(self) -> None:
        if self._i != self._n:
            raise RuntimeError(f"DR samplers made {self._i} of {self._n} recorded draws")
