"""Draws added in stages: a group-sequential t-test over training draws (SPEC §10, revision 6).

A row is looked at when each model has n_1 < n_2 < … < n_K trained draws (``Design.looks``). At
each look a difference test (``holds`` or ``contradicted``) and an equivalence test against
±margin (``equivalent``) share the looks, with boundaries from ``boundaries``. A row stops at its
first decision and is ``inconclusive`` if undecided at the last look. The family's α is spent
over the rows (Bonferroni) and over the looks. The tests in full: docs/modules.md; error rates:
``cape.study.stats.sequential_calibration`` and docs/question.md.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

HOLDS, CONTRADICTED, INCONCLUSIVE = "holds", "contradicted", "inconclusive"
EQUIVALENT = "equivalent"
"""No practical difference: the row's interval lies inside ±margin (SPEC §10, revision 6)."""
OPEN = "open"
"""Not decided yet: more draws come at the next look."""
SETTLED = (HOLDS, CONTRADICTED, EQUIVALENT)
FUTILE = "inconclusive (futile)"
"""Stopped buying draws: its chance of settling by the cap fell below ``Design.futility``."""

BOUNDARY_TRIALS = 1_000_000
"""Monte Carlo paths of the t-process each boundary is a quantile of."""


def spent(looks: Sequence[int], alpha: float, rho: float) -> np.ndarray:
    """The α spent by each look, cumulated: ``alpha · (n_k / n_K)^rho`` (Kim–DeMets power
    family: ρ = 1 spends evenly over the information, ρ = 3 keeps most for the last look)."""
    n = np.asarray(looks, dtype=float)
    return alpha * (n / n[-1]) ** rho


@functools.lru_cache(maxsize=32)
def boundaries(
    looks: tuple[int, ...],
    alpha: float,
    rho: float,
    two_sided: bool,
    trials: int = BOUNDARY_TRIALS,
    seed: int = 0,
) -> tuple[float, ...]:
    """The critical values c_1 … c_K of the t-statistic at the looks: under normal draws with
    no effect, the chance that ``|T_k| ≥ c_k`` (``two_sided``) or ``T_k ≥ c_k`` at look k and at
    no earlier look is the α spent there (``spent``). The first look's is Student's t quantile
    (nothing comes before it); each later one a quantile of the paths that crossed no earlier
    boundary, by seeded Monte Carlo over ``trials`` paths (the t-process is pivotal); ``inf``
    where a look spends less than one path's worth."""
    from scipy import stats

    if len(looks) < 1 or any(b <= a for a, b in itertools.pairwise(looks)):
        raise ValueError(f"looks must increase: {looks}")
    if looks[0] < 2:
        raise ValueError(f"the first look needs two draws or more (a spread): {looks}")
    rng = np.random.default_rng(seed)
    alive = np.ones(trials, dtype=bool)
    total = np.zeros(trials)
    squares = np.zeros(trials)
    previous, out = 0, []
    cumulative = spent(looks, alpha, rho)
    for k, n in enumerate(looks):
        for start in range(previous, n, 10):  # at most 10 draws' paths in memory at once
            block = rng.standard_normal((trials, min(10, n - start)))
            total += block.sum(axis=1)
            squares += (block**2).sum(axis=1)
        previous = n
        mean = total / n
        sd = np.sqrt(np.maximum(squares - n * mean**2, 0.0) / (n - 1))
        t = mean / (sd / math.sqrt(n))
        stat = np.abs(t) if two_sided else t
        spend = cumulative[k] - (cumulative[k - 1] if k else 0.0)
        if k == 0:  # exactly: the first look's crossing is the t-test's own tail
            c = float(stats.t.isf(spend / 2 if two_sided else spend, n - 1))
            out.append(c)
            alive &= ~(stat >= c)
            continue
        count = round(spend * trials)
        candidates = np.sort(stat[alive])[::-1]
        if count < 1 or count > candidates.size:
            out.append(math.inf)
            continue
        c = float(candidates[count - 1])
        out.append(c)
        alive &= ~(stat >= c)
    return tuple(out)


@dataclass(frozen=True)
class Design:
    """The planned looks (trained draws per model at each), the family's α, how many rows
    share it, the spending exponent, and the futility level (a row whose chance of settling by
    the cap falls below it stops buying draws; 0: never). ``difference`` and ``equivalence`` are
    the critical values of |T| and of each one-sided equivalence statistic at each look."""

    looks: tuple[int, ...]
    rows: int
    alpha: float = 0.05
    rho: float = 2.0
    futility: float = 0.0

    @property
    def per_row(self) -> float:
        """α of one row's test (Bonferroni over the family)."""
        return self.alpha / self.rows

    @property
    def difference(self) -> tuple[float, ...]:
        return boundaries(self.looks, self.per_row, self.rho, True)

    @property
    def equivalence(self) -> tuple[float, ...]:
        return boundaries(self.looks, self.per_row, self.rho, False)

    @property
    def cap(self) -> int:
        return self.looks[-1]

    def look_of(self, draws: int) -> int:
        """The index of the look made at ``draws`` draws (ValueError if none is)."""
        if draws not in self.looks:
            raise ValueError(f"{draws} draws is no look of {self.looks}")
        return self.looks.index(draws)


@dataclass(frozen=True)
class Decided:
    """``decide``'s answer, one entry per row: the decision, the mean, its standard error, the
    difference's repeated interval ``mean ± c_k·se`` and the equivalence interval
    ``mean ± e_k·se`` (all ``mean`` where the values do not vary), and which rows had no spread."""

    decision: np.ndarray
    mean: np.ndarray
    se: np.ndarray
    low: np.ndarray
    high: np.ndarray
    equivalence_low: np.ndarray
    equivalence_high: np.ndarray
    flat: np.ndarray


def decide(
    x: np.ndarray,
    design: Design,
    margin: float | None,
    side: float,
    last: bool = False,
    floor: np.ndarray | float = 0.0,
) -> Decided:
    """The decision rule at one look, on many rows at once: ``x`` is ``… × n`` draws' effects
    (n a look of ``design``). ``holds`` / ``contradicted`` (by ``side``, the sign tested) where
    |T| reaches the difference boundary, else ``equivalent`` where ``mean ± e·se`` lies inside
    ±``margin`` (no margin: never), else ``OPEN`` (``INCONCLUSIVE`` at the ``last`` look).
    Values that do not vary decide nothing. ``floor`` is the least variance a draw's effect can
    have, σ²_within × mean(1 / seeds) from its seeds (``components``): a draw averages its
    seeds, so its effect varies at least that much, and the draws' variance is taken as no less
    (it guards against data of mostly exact ties, such as failure counts of models that rarely
    fail; it only widens intervals). ``look`` and the calibration both call it."""
    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    k = design.look_of(n)
    mean = x.mean(axis=-1)
    sd = x.std(axis=-1, ddof=1)
    flat = ~(sd > 1e-12 * np.maximum(1.0, np.abs(x).max(axis=-1)))
    sd = np.sqrt(np.maximum(sd**2, floor))
    se = np.where(flat, 0.0, sd / math.sqrt(n))
    c, e = design.difference[k], design.equivalence[k]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(flat, 0.0, np.abs(mean) / np.where(flat, 1.0, se))
    differ = ~flat & (t >= c)
    decision = np.full(mean.shape, INCONCLUSIVE if last else OPEN, dtype=object)
    decision[differ & ((mean > 0) == (side > 0))] = HOLDS
    decision[differ & ((mean > 0) != (side > 0))] = CONTRADICTED
    if margin is not None:
        tied = (x[..., :, None] == x[..., None, :]).sum(axis=-1).max(axis=-1)
        inside = ~flat & ~differ & (mean - e * se > -margin) & (mean + e * se < margin)
        inside &= 2 * tied <= n  # a spread carried by fewer than half the draws shows nothing
        decision[inside] = EQUIVALENT
    low, high = mean - c * se, mean + c * se
    return Decided(decision, mean, se, low, high, mean - e * se, mean + e * se, flat)


@dataclass(frozen=True)
class Look:
    """One row at one look: its draws, the mean of their effects, its standard error, the
    difference's repeated interval (``mean ± c_k·se``: valid over all looks together), the
    equivalence interval (``mean ± e_k·se``), the decision (``OPEN`` before the last look when
    undecided), why it is undecided, and its chance of settling by the cap (NaN: not asked)."""

    draws: int
    estimate: float
    se: float
    low: float
    high: float
    equivalence_low: float
    equivalence_high: float
    decision: str
    why: str = ""
    chance: float = math.nan
    spread: Any = None
    """The row's draws × seeds structure at this look (``cape.study.question.looks.Spread``)."""


def look(
    values: Sequence[float],
    design: Design,
    margin: float | None,
    side: float,
    last: bool = False,
    floor: float = 0.0,
) -> Look:
    """The decision on one row from its draws' effects ``values`` at the look of their number
    (``decide`` on one row, with its variance ``floor``); non-finite values are left out."""
    x = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    n = x.size
    design.look_of(n)
    d = decide(x, design, margin, side, last, floor)
    why = f"no spread over {n} draws" if bool(d.flat) else ""
    return Look(
        n,
        float(d.mean),
        float(d.se),
        float(d.low),
        float(d.high),
        float(d.equivalence_low),
        float(d.equivalence_high),
        str(d.decision),
        why,
    )


def settle_chance(
    estimate: np.ndarray | float,
    variance: np.ndarray | float,
    draws: int,
    later_variance: np.ndarray | float,
    design: Design,
    margin: float | None,
    at: int = -1,
) -> np.ndarray:
    """A row's conditional chance of settling at look ``at`` (default: the cap's) under the
    current estimate:
    its ``draws`` draws' effects have mean ``estimate`` and variance ``variance``, the cap's
    remaining draws vary by ``later_variance`` around the estimate. The cap's mean is then
    normal around the estimate with variance (N − n)·later_variance / N², its standard error
    taken at its expectation; the chance is that it crosses the difference boundary or lands
    inside the equivalence region. Earlier looks are left out (they only add chances), so the
    futility it drives errs towards stopping; being non-binding, it can only remove decisions.
    The cap's mean here is N = ``design.looks[at]`` draws' (``variance`` the cap's draws' effects
    of the remaining N − n, ``later_variance`` each)."""
    from scipy.special import ndtr

    n, cap = draws, design.looks[at]
    estimate = np.asarray(estimate, float)
    future = max(cap - n, 0) * np.asarray(later_variance, float)
    se = np.sqrt((n * np.asarray(variance, float) + future) / cap / cap)
    spread = np.sqrt(future) / cap
    c, e = design.difference[at], design.equivalence[at]
    half = np.zeros_like(se) if margin is None else np.maximum(margin - e * se, 0.0)
    far = c * se
    with np.errstate(divide="ignore", invalid="ignore"):

        def within(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
            return np.clip(ndtr((hi - estimate) / spread) - ndtr((lo - estimate) / spread), 0, 1)

        undecided = within(half, far) + within(-far, -half)  # half ≤ |M| < c·se
        chance = np.where(half >= far, 1.0, 1.0 - np.clip(undecided, 0.0, 1.0))
    return np.where(spread > 0, chance, np.nan)


def components(
    sums: np.ndarray, squares: np.ndarray, counts: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """σ²_between and σ²_within of ``… × draws`` tables given each draw's sum, sum of squares
    and number of seeds (draws may have different seeds): one-way random effects, σ²_within
    pooled over the draws' seeds, σ²_between the variance of the draws' means less the mean of
    σ²_within / seeds, floored at zero. Without two seeds in any draw σ²_within is 0."""
    counts = np.broadcast_to(np.asarray(counts, float), np.shape(sums))
    resid = np.maximum(squares - sums**2 / counts, 0.0).sum(axis=-1)
    dof = (counts - 1).sum(axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        within = np.where(dof > 0, resid / np.where(dof > 0, dof, 1), 0.0)
    means = sums / counts
    spread = means.var(axis=-1, ddof=1)
    between = np.maximum(spread - (within[..., None] / counts).mean(axis=-1), 0.0)
    return between, within


def variance_components(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``components`` of balanced ``… × draws × seeds`` tables."""
    seeds = values.shape[-1]
    counts = np.full(values.shape[:-1], seeds)
    return components(values.sum(axis=-1), (values**2).sum(axis=-1), counts)


def seeds_per_draw(
    between: np.ndarray | float,
    within: np.ndarray | float,
    cost_ratio: float,
    least: int,
    most: int,
) -> np.ndarray:
    """The two-stage sampling optimum: the seeds per draw that minimise the variance of the mean
    effect, σ²_b / R + σ²_w / (R·n), for a given CPU, R·(c_draw + n·c_seed), are
    ``n = √(c_draw / c_seed · σ²_w / σ²_b)`` (``cost_ratio`` = c_draw / c_seed), rounded and
    kept within [``least``, ``most``] (``most`` where the draws do not differ at all)."""
    between, within = np.asarray(between, float), np.asarray(within, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        n = np.sqrt(cost_ratio * within / between)
    n = np.where(between > 0, n, most)
    return np.clip(np.rint(np.nan_to_num(n, nan=most)), least, most).astype(int)


def payoff_seeds(
    chance: Callable[[int], np.ndarray],
    buying: np.ndarray,
    draws_left: int,
    draw_cost: np.ndarray,
    seed_cost: np.ndarray,
    least: int,
    most: int,
) -> np.ndarray:
    """The seeds per later draw that pay best: of ``least`` … ``most``, the number n that
    maximises the expected rows settled at the next look per CPU-second of its draws,
    Σ chance(n) / Σ over the models still buying draws of ``draws_left``·(draw_cost +
    n·seed_cost), ``draws_left`` the draws to that look. ``chance(n)`` is
    ``… × rows`` (0 for rows not open), ``buying`` ``… × models``; returns ``…`` seeds (``least``
    where nothing is bought)."""
    candidates = range(least, most + 1)
    best = np.full(np.shape(buying)[:-1], least)
    score = np.full(best.shape, -np.inf)
    for n in candidates:
        settled = np.nan_to_num(chance(n), nan=0.0).sum(axis=-1)
        cpu = (buying * draws_left * (draw_cost + n * seed_cost)).sum(axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            value = np.where(cpu > 0, settled / cpu, -np.inf)
        better = value > score + 1e-15
        best = np.where(better, n, best)
        score = np.where(better, value, score)
    return best
