"""How often a verdict's interval is wrong: simulated draws × seeds (SPEC §10, turn 4).

Nested data as a study makes them: each training draw's effect varies around the true effect
with spread ``σ_between`` (in units of the seeds' spread ``σ_within`` = 1: ``ratio``), and each
of a draw's seeds around its draw's effect with ``σ_within``. With no true effect, the rate at
which a method's 95 % interval excludes zero is its false-verdict rate; with one, the rate at
which it excludes zero is its power. ``t_over_draws`` is the scorecard's method
(``cape.study.verdicts.t_interval`` over the draws' means, as ``interval`` computes it);
``bootstrap_two_level`` is the two-level percentile bootstrap the scorecard used before (turn
3), kept here only to show why it was retired (docs/study.md: 18–21 % at three draws).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cape.study.verdicts import t_interval

Method = Callable[[np.ndarray, float, np.random.Generator], tuple[np.ndarray, np.ndarray]]
"""(trials × draws × seeds effects, level, generator) → each trial's interval (low, high)."""


def nested(
    rng: np.random.Generator, trials: int, draws: int, seeds: int, ratio: float, effect: float = 0.0
) -> np.ndarray:
    """trials × draws × seeds effects: the true ``effect`` plus a draw's deviation (sd
    ``ratio``) plus a seed's (sd 1)."""
    between = rng.normal(0.0, 1.0, size=(trials, draws, 1)) * ratio
    within = rng.normal(0.0, 1.0, size=(trials, draws, seeds))
    return effect + between + within


def t_over_draws(
    data: np.ndarray, level: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """The scorecard's interval: Student's t over the draws' seed-averaged effects."""
    return t_interval(data.mean(axis=-1), level)


def bootstrap_two_level(
    data: np.ndarray, level: float, rng: np.random.Generator, resamples: int = 2000
) -> tuple[np.ndarray, np.ndarray]:
    """The retired interval: draws resampled with replacement, then the seeds within each
    drawn draw; the statistic is the mean over the drawn draws of their seeds' mean; the
    interval its percentiles."""
    trials, draws, seeds = data.shape
    lows, highs = np.empty(trials), np.empty(trials)
    tail = 100 * (1 - level) / 2
    for k in range(trials):
        picked = rng.integers(0, draws, size=(resamples, draws))
        inner = rng.integers(0, seeds, size=(resamples, draws, seeds))
        statistic = data[k][picked[..., None], inner].mean(axis=(1, 2))
        lows[k], highs[k] = np.percentile(statistic, [tail, 100 - tail])
    return lows, highs


METHODS: dict[str, Method] = {
    "t over draws": t_over_draws,
    "two-level bootstrap": bootstrap_two_level,
}


def exclusion_rate(
    method: Method,
    draws: int,
    ratio: float,
    effect: float = 0.0,
    trials: int = 2000,
    seeds: int = 5,
    level: float = 0.95,
    seed: int = 0,
) -> float:
    """The share of ``trials`` simulated studies whose interval excludes zero (seeded)."""
    rng = np.random.default_rng(seed)
    data = nested(rng, trials, draws, seeds, ratio, effect)
    low, high = method(data, level, rng)
    return float(np.mean((low > 0) | (high < 0)))
