"""Draws added in stages: a group-sequential t-test over training draws (SPEC §10, revision 6).

A row is looked at when each model has n_1 < n_2 < … < n_K trained draws (``Design.looks``). At
each look a difference test (``holds`` or ``contradicted``) and an equivalence test against
±margin (``equivalent``) share the looks, with boundaries from ``boundaries``. A row stops at its
first decision and is ``inconclusive`` if undecided at the last look. The family's α is spent
over the rows (Bonferroni) and over the looks. The tests in full: docs/modules.md; error rates:
``cape.study.sequential_calibration`` and docs/question.md.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

HOLDS, CONTRADICTED, INCONCLUSIVE = "holds", "contradicted", "inconclusive"
EQUIVALENT = "equivalent"
"""No practical difference: the row's interval lies inside ±margin (SPEC §10, revision 6)."""
OPEN = "open"
"""Not decided yet: more draws come at the next look."""
SETTLED = (HOLDS, CONTRADICTED, EQUIVALENT)

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
    share it, and the spending exponent; ``difference`` and ``equivalence`` are the critical
    values of |T| and of each one-sided equivalence statistic at each look."""

    looks: tuple[int, ...]
    rows: int
    alpha: float = 0.05
    rho: float = 2.0

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

    def look_of(self, draws: int) -> int:
        """The index of the look made at ``draws`` draws (ValueError if none is)."""
        if draws not in self.looks:
            raise ValueError(f"{draws} draws is no look of {self.looks}")
        return self.looks.index(draws)


@dataclass(frozen=True)
class Look:
    """One row at one look: its draws, the mean of their effects, its standard error, the
    difference's repeated interval (``mean ± c_k·se``), the equivalence interval
    (``mean ± e_k·se``), and the decision (``OPEN`` before the last look when undecided)."""

    draws: int
    estimate: float
    se: float
    low: float
    high: float
    equivalence_low: float
    equivalence_high: float
    decision: str
    why: str = ""


def look(
    values: Sequence[float], design: Design, margin: float | None, side: float, last: bool = False
) -> Look:
    """The decision on one row from its draws' effects ``values`` at the look of their number:
    ``holds`` / ``contradicted`` (by ``side``, the sign tested) when |T| reaches the difference
    boundary, else ``equivalent`` when the interval ``mean ± e·se`` lies inside ±``margin`` (no
    margin: never), else ``OPEN``, or ``INCONCLUSIVE`` at the last look (``last``: the cap, or
    the last look this row gets). Values that do not vary decide nothing (no spread)."""
    x = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    n = x.size
    undecided = INCONCLUSIVE if last else OPEN
    k = design.look_of(n)
    mean = float(x.mean())
    sd = float(x.std(ddof=1))
    se = sd / math.sqrt(n)
    if not sd > 1e-12 * max(1.0, float(np.abs(x).max())):
        return Look(n, mean, 0.0, mean, mean, mean, mean, undecided, f"no spread over {n} draws")
    c, e = design.difference[k], design.equivalence[k]
    low, high = mean - c * se, mean + c * se
    elow, ehigh = mean - e * se, mean + e * se
    if abs(mean) / se >= c:
        decision = HOLDS if (mean > 0) == (side > 0) else CONTRADICTED
    elif margin is not None and -margin < elow and ehigh < margin:
        decision = EQUIVALENT
    else:
        decision = undecided
    return Look(n, mean, se, low, high, elow, ehigh, decision)


def simulate(
    design: Design,
    draw_values: np.ndarray,
    margin: float | None,
    side: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The procedure on many simulated rows at once: ``draw_values`` is trials × n_K, each
    draw's effect (already averaged over its seeds), in the order draws are added. Returns each
    trial's decision (one of ``SETTLED`` or ``INCONCLUSIVE``) and the draws it used. The same
    rule as ``look``, vectorised."""
    trials = draw_values.shape[0]
    decision = np.full(trials, INCONCLUSIVE, dtype=object)
    used = np.full(trials, design.looks[-1])
    open_ = np.ones(trials, dtype=bool)
    for k, n in enumerate(design.looks):
        x = draw_values[:, :n]
        mean = x.mean(axis=1)
        sd = x.std(axis=1, ddof=1)
        spread = sd > 1e-12 * np.maximum(1.0, np.abs(x).max(axis=1))
        se = np.where(spread, sd / math.sqrt(n), np.inf)
        c, e = design.difference[k], design.equivalence[k]
        differ = open_ & spread & (np.abs(mean) / se >= c)
        decision[differ & ((mean > 0) == (side > 0))] = HOLDS
        decision[differ & ((mean > 0) != (side > 0))] = CONTRADICTED
        settled = differ
        if margin is not None:
            inside = (mean - e * se > -margin) & (mean + e * se < margin)
            equivalent = open_ & spread & ~differ & inside
            decision[equivalent] = EQUIVALENT
            settled = settled | equivalent
        used[settled] = n
        open_ &= ~settled
    return decision, used


def variance_components(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """σ²_between and σ²_within of balanced ``… × draws × seeds`` tables (one-way random
    effects, the ANOVA estimates: σ²_within the mean within-draw variance, σ²_between the
    variance of the draws' means less σ²_within / seeds, floored at zero)."""
    seeds = values.shape[-1]
    within = values.var(axis=-1, ddof=1).mean(axis=-1) if seeds > 1 else np.zeros(values.shape[:-2])
    between = np.maximum(values.mean(axis=-1).var(axis=-1, ddof=1) - within / seeds, 0.0)
    return between, within


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
