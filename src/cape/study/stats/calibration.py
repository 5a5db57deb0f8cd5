"""How often a verdict's interval is wrong: simulated draws × seeds (SPEC §10).

Nested data as a study makes them: each training draw's effect varies around the true effect
with spread ``σ_between`` (in units of the seeds' spread ``σ_within`` = 1: ``ratio``), and each
of a draw's seeds around its draw's effect with ``σ_within``. With no true effect, the rate at
which a method's 95 % interval excludes zero is its false-verdict rate; with one, the rate at
which it excludes zero is its power. ``t_over_draws`` is the scorecard's method
(``cape.study.stats.verdicts.t_interval`` over the draws' means, as ``interval`` computes it).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cape.study.stats.verdicts import t_interval

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


def fdr_family(
    draws: int,
    rows: int = 20,
    effects: int = 10,
    effect: float = 3.0,
    ratio: float = 1.0,
    trials: int = 1000,
    seeds: int = 5,
    q: float = 0.05,
    seed: int = 0,
) -> tuple[float, float, float]:
    """Families of ``rows`` table-8 rows, ``effects`` of them with a true effect of ``effect``
    σ_between (the others none), each row measured over ``draws`` × ``seeds`` (``nested``):
    the false-discovery rate of the Benjamini–Hochberg verdicts (the mean over trials of the
    share of decided rows that are null or on the wrong side), the same share without the
    adjustment, and the adjusted verdicts' power (the share of true effects decided the right
    way). The p-values are the scorecard's own (``t_test`` over the draws' means)."""
    from cape.study.stats.verdicts import CONTRADICTED, HOLDS, INCONCLUSIVE, fdr_verdicts, t_test

    rng = np.random.default_rng(seed)
    truth = np.zeros(rows)
    truth[:effects] = effect * max(ratio, 1e-9)
    fdr, raw_fdr, power = [], [], []
    for _ in range(trials):
        data = nested(rng, rows, draws, seeds, ratio) + truth[:, None, None]
        low, high, p = t_test(data.mean(axis=-1))
        said = [HOLDS if lo > 0 else CONTRADICTED if hi < 0 else INCONCLUSIVE
                for lo, hi in zip(low, high, strict=True)]  # fmt: skip
        adjusted = fdr_verdicts(list(p), said, q)
        for verdicts, out in ((adjusted, fdr), (said, raw_fdr)):
            decided = np.array([v != INCONCLUSIVE for v in verdicts])
            right = np.array([v == HOLDS for v in verdicts]) & (truth > 0)
            false = decided & ~right
            out.append(false.sum() / max(1, decided.sum()))
        right = np.array([v == HOLDS for v in adjusted]) & (truth > 0)
        power.append(right.sum() / max(1, effects))
    return float(np.mean(fdr)), float(np.mean(raw_fdr)), float(np.mean(power))


def replaced_failures(
    draws: int,
    fail: float = 0.5,
    cap_factor: int = 2,
    failed_shift: float = 5.0,
    ratio: float = 1.0,
    trials: int = 2000,
    seeds: int = 5,
    seed: int = 0,
) -> tuple[float, float]:
    """A model with no true effect whose trainings fail with probability ``fail``: a failed
    network's effect is off by ``failed_shift`` σ_between (it drives differently). Per trial
    its trainings are tried in seed order up to ``cap_factor`` × ``draws`` (cape.training.draws),
    and the verdict is the scorecard's: ``class_interval`` and ``verdict`` over the trained
    draws (inconclusive with fewer than two). Returns the false-verdict rate over the trained draws
    and, for comparison, over the first ``draws`` trainings with the failed ones kept."""
    from cape.study.stats.verdicts import INCONCLUSIVE, class_interval, interval, verdict
    from cape.training.draws import choose_training
    from cape.training.outcome import Outcome

    rng = np.random.default_rng(seed)
    cap = cap_factor * draws
    false_trained, false_kept = 0, 0
    for _ in range(trials):
        failed = rng.random(cap) < fail
        data = (
            nested(rng, 1, cap, seeds, ratio)[0]
            + np.where(failed, failed_shift * ratio, 0)[:, None]
        )
        outcomes = [Outcome(k, not failed[k]) for k in range(cap)]
        chosen = [choose_training(r, cap, outcomes.__getitem__) for r in range(draws)]
        trained = {c.index: list(data[c.index]) for c in chosen if c.trained}
        false_trained += verdict(class_interval(trained, draws), -1.0) != INCONCLUSIVE
        kept = {k: list(data[k]) for k in range(draws)}
        false_kept += verdict(interval(kept), -1.0) != INCONCLUSIVE
    return false_trained / trials, false_kept / trials
