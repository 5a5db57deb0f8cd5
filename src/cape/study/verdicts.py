"""Three-valued verdicts from intervals that span training replicates and seeds (SPEC §10).

An effect (EPM's lap time minus DDM's, a relative error, a difference of failure counts) is
measured once per (training replicate, disturbance seed). Its interval is a two-level
bootstrap: each resample draws the replicates with replacement, then, within each drawn
replicate, its seeds with replacement; the statistic is the mean over the drawn replicates of
their seeds' mean, so a replicate weighs the same whatever its number of seeds. The 95 %
interval is the 2.5 and 97.5 percentiles of the resampled statistic. With one replicate this
is the ordinary bootstrap over seeds; with one value per replicate (an open-loop error), the
bootstrap over replicates.

Why not a library's: ``scipy.stats.bootstrap`` resamples each of several samples
independently (seeds within every replicate: the replicates themselves never resampled) and
rliable's stratified bootstrap does the same within tasks. Both are one level; the
between-replicate spread, which is the point of replicates, would be missing. The two-level
draw is a few lines of NumPy with a seeded generator, checked against a case worked by hand
and, for one replicate, against ``scipy.stats.bootstrap`` (tests/test_verdicts.py).

A verdict compares the interval with zero on the paper's side: ``holds`` when it lies wholly
there, ``contradicted`` when it lies wholly on the other side, ``inconclusive`` when it
contains zero. An ordering (EPM < DDM < DPM) is each of its pairwise differences: it holds
when all hold, is contradicted when any is, and is inconclusive otherwise.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

HOLDS, CONTRADICTED, INCONCLUSIVE = "holds", "contradicted", "inconclusive"
VERDICTS = (HOLDS, CONTRADICTED, INCONCLUSIVE)


@dataclass(frozen=True)
class Interval:
    """An effect's estimate (mean over replicates of their seeds' mean) and its interval."""

    estimate: float
    low: float
    high: float
    replicates: int
    values: int

    def contains_zero(self) -> bool:
        return self.low <= 0.0 <= self.high


def _groups(effects: Mapping[int, Sequence[float]]) -> list[np.ndarray]:
    """The finite values of each replicate that has any."""
    groups = []
    for values in effects.values():
        x = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
        if x.size:
            groups.append(x)
    return groups


def two_level_distribution(
    effects: Mapping[int, Sequence[float]], resamples: int = 10_000, seed: int = 0
) -> np.ndarray:
    """The bootstrap distribution of the mean effect: replicates, then seeds within each
    (``effects``: replicate → its per-seed values)."""
    groups = _groups(effects)
    if not groups:
        return np.empty(0)
    rng = np.random.default_rng(seed)
    n = len(groups)
    picks = rng.integers(0, n, size=(resamples, n))  # the replicates each resample draws
    total = np.zeros(resamples)
    for position in range(n):
        for g, x in enumerate(groups):
            chosen = np.flatnonzero(picks[:, position] == g)
            if chosen.size:
                inner = rng.integers(0, x.size, size=(chosen.size, x.size))
                total[chosen] += x[inner].mean(axis=1)
    return total / n


def interval(
    effects: Mapping[int, Sequence[float]],
    level: float = 0.95,
    resamples: int = 10_000,
    seed: int = 0,
) -> Interval:
    """The effect's estimate and its two-level percentile interval (NaN without values)."""
    groups = _groups(effects)
    values = sum(g.size for g in groups)
    if not groups:
        return Interval(math.nan, math.nan, math.nan, 0, 0)
    estimate = float(np.mean([g.mean() for g in groups]))
    if all(np.all(g == g[0]) for g in groups) and len({float(g[0]) for g in groups}) == 1:
        return Interval(estimate, estimate, estimate, len(groups), values)  # nothing varies
    dist = two_level_distribution(effects, resamples, seed)
    tail = 100 * (1 - level) / 2
    low, high = np.percentile(dist, [tail, 100 - tail])
    return Interval(estimate, float(low), float(high), len(groups), values)


def verdict(span: Interval, paper_sign: float) -> str:
    """``holds`` / ``contradicted`` / ``inconclusive`` for an effect the paper says is of sign
    ``paper_sign`` (+1 or −1); an effect without values is inconclusive."""
    if math.isnan(span.low) or paper_sign == 0 or span.contains_zero():
        return INCONCLUSIVE
    same = (span.low > 0) == (paper_sign > 0)
    return HOLDS if same else CONTRADICTED


def exact_verdict(value: float, paper_sign: float) -> str:
    """A deterministic row (a parameter count): holds or contradicted, by its sign (a tie
    contradicts a strict order)."""
    if math.isnan(value):
        return INCONCLUSIVE
    return HOLDS if value * paper_sign > 0 else CONTRADICTED


def combine(verdicts: Iterable[str]) -> str:
    """One ordering from its pairwise verdicts: holds when all hold, contradicted when any is."""
    seen = list(verdicts)
    if not seen:
        return INCONCLUSIVE
    if all(v == HOLDS for v in seen):
        return HOLDS
    return CONTRADICTED if CONTRADICTED in seen else INCONCLUSIVE
