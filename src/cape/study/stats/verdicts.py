"""Three-valued verdicts from intervals whose unit is the training draw (SPEC §10).

An interval is Student's t over the draws' effects, each averaged over its seeds (over the seeds
with one draw), and carries the t-test's two-sided p-value. ``verdict`` gives ``holds`` or
``contradicted`` when it lies wholly on the paper's side of zero or wholly on the other, else
``inconclusive``; an ordering holds when all its pairs hold and is contradicted when any is. A
point decides nothing unless its row is exact (``exact_verdict``); ``Interval.why`` says why.
``fdr_verdicts`` adjusts a family of rows (Benjamini–Hochberg). Reasoning: docs/modules.md.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from cape.errors import CapeError

HOLDS, CONTRADICTED, INCONCLUSIVE = "holds", "contradicted", "inconclusive"
EQUIVALENT = "equivalent"
"""No practical difference: the two one-sided tests put the effect inside ±margin (SPEC §10,
revision 6); only a row whose metric has a margin (config ``scorecard.margins``) can be."""
VERDICTS = (HOLDS, CONTRADICTED, EQUIVALENT, INCONCLUSIVE)

DRAWS, SEEDS, POINT, NONE = "draws", "seeds", "point", "none"
"""What an interval is taken over: the draws' effects, one draw's seeds, nothing that varies,
no values at all."""

NO_EFFECT = "no effect measured"


@dataclass(frozen=True)
class Interval:
    """An effect's estimate (the mean of the draws' effects), its interval, what the interval
    is taken over (``unit``), how many draws and values it rests on, the spread of the unit's
    values (the draws' effects, or one draw's seeds: ``sd``, ddof 1), the two-sided p-value of
    the t-test against zero, and ``why`` a point decides nothing ("" for an interval)."""

    estimate: float
    low: float
    high: float
    replicates: int
    values: int
    unit: str = DRAWS
    sd: float = math.nan
    p: float = math.nan
    why: str = ""

    def contains_zero(self) -> bool:
        return self.low <= 0.0 <= self.high


class UnusableEffectsError(CapeError, ValueError):
    """Effects no interval can summarise: a value that is infinite, or values so large that
    their mean, spread or interval overflows (1e308 and −1e308: a mean of 0 inside ±inf).
    Screen such values first (a broken run: cape.study.claims.leaderboard does); a ``CapeError``, so
    that a command that meets one says it in one line."""


def _groups(effects: Mapping[int, Sequence[float]]) -> list[np.ndarray]:
    """The values of each draw that has any (a missing value, None or NaN, left out);
    ``UnusableEffectsError`` for an infinite one."""
    groups = []
    for replicate, values in effects.items():
        x = np.asarray([v for v in values if v is not None and not math.isnan(v)], dtype=float)
        if np.isinf(x).any():
            raise UnusableEffectsError(
                f"draw {replicate}'s effect {x[np.isinf(x)][0]:g} is not a finite number, so no "
                "interval can summarise it; screen such values (a broken run) first"
            )
        if x.size:
            groups.append(x)
    return groups


def _overflowed(numbers: Sequence[float], groups: Sequence[np.ndarray]) -> None:
    """``UnusableEffectsError`` where a statistic of finite ``groups`` is not finite."""
    if all(math.isfinite(v) for v in numbers):
        return
    largest = max(float(np.abs(g).max()) for g in groups)
    raise UnusableEffectsError(
        f"effects of magnitude up to {largest:.3g} cannot be summarised: their mean, spread or "
        "interval overflows; screen such values (a broken run) first"
    )


def draw_effects(effects: Mapping[int, Sequence[float]]) -> dict[int, float]:
    """Replicate → its effect averaged over its seeds (draws without a finite value left out)."""
    out = {}
    for replicate, values in effects.items():
        x = _groups({replicate: values})
        if x:
            out[replicate] = float(x[0].mean())
    return out


def t_interval(x: np.ndarray, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Student's t interval of the mean along the last axis of ``x`` (n − 1 degrees of
    freedom), by ``scipy.stats.ttest_1samp``: one interval per row, so that the calibration
    (cape.study.stats.calibration) runs the very computation ``interval`` does on thousands of
    trials."""
    ci = stats.ttest_1samp(x, 0.0, axis=-1).confidence_interval(confidence_level=level)
    return np.asarray(ci.low), np.asarray(ci.high)


def t_test(x: np.ndarray, level: float = 0.95) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``t_interval`` and the two-sided p-value of the same one-sample t-test against zero."""
    result = stats.ttest_1samp(x, 0.0, axis=-1)
    ci = result.confidence_interval(confidence_level=level)
    return np.asarray(ci.low), np.asarray(ci.high), np.asarray(result.pvalue)


def _no_spread(x: np.ndarray) -> bool:
    """Values equal to rounding (a tie in every draw, an integer count that never changes)."""
    return bool(np.ptp(x) <= 1e-12 * max(1.0, float(np.abs(x).max())))


def interval(effects: Mapping[int, Sequence[float]], level: float = 0.95) -> Interval:
    """The effect's estimate and its ``level`` interval (``effects``: replicate → the effect's
    values, one per seed or one for the draw): Student's t over the draws' means with two or
    more draws, over the seeds with one; NaN without values; a point, with ``why``, from one
    value or values that do not vary. A missing value (None, NaN) is left out;
    ``UnusableEffectsError`` (a ``ValueError``) for an infinite value, or for values whose
    mean, spread or interval overflows."""
    groups = _groups(effects)
    values = sum(g.size for g in groups)
    if not groups:
        return Interval(math.nan, math.nan, math.nan, 0, 0, NONE, why="no values")
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused, not warned
        if len(groups) >= 2:
            x, unit = np.array([g.mean() for g in groups]), DRAWS
        else:
            x, unit = groups[0], SEEDS
        estimate = float(x.mean())
        _overflowed([estimate], groups)
        if x.size < 2:
            return Interval(estimate, estimate, estimate, len(groups), values, POINT,
                            why="one value")  # fmt: skip
        if _no_spread(x):
            why = f"no spread over {x.size} {unit}"
            return Interval(estimate, estimate, estimate, len(groups), values, POINT, 0.0, why=why)
        low, high, p = t_test(x, level)
        sd = float(x.std(ddof=1))
        _overflowed([float(low), float(high), sd], groups)
    return Interval(estimate, float(low), float(high), len(groups), values, unit, sd, float(p))


def class_interval(
    effects: Mapping[int, Sequence[float]], study_draws: int, level: float = 0.95
) -> Interval:
    """``interval`` for a claim about a model class in a study of ``study_draws`` draws: with
    two or more, one draw's seeds say nothing about the class, so an effect left with values
    in fewer than two draws (the others failed to train, or have none) is a point that decides
    nothing; with one (the default target), the interval over that draw's seeds is about its
    networks, as the table says."""
    span = interval(effects, level)
    if study_draws >= 2 and span.replicates == 1:
        return Interval(
            span.estimate, span.estimate, span.estimate, span.replicates, span.values, POINT,
            why=f"one draw of {study_draws} has a value",
        )  # fmt: skip
    return span


def verdict(span: Interval, paper_sign: float) -> str:
    """``holds`` / ``contradicted`` / ``inconclusive`` for an effect the paper says is of sign
    ``paper_sign`` (+1 or −1); an effect without values, or a point (``span.why``), is
    inconclusive: a random quantity needs a spread to be decided (rows declared exact use
    ``exact_verdict``)."""
    if span.unit in (POINT, NONE) or math.isnan(span.low) or paper_sign == 0:
        return INCONCLUSIVE
    if span.contains_zero():
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


def equivalence_p(effects: Mapping[int, Sequence[float]], margin: float, study_draws: int) -> float:
    """The p-value of the two one-sided tests that the effect lies inside ±``margin``
    (``statsmodels``' TOST, ``DescrStatsW.ttost_mean``), over the same values as
    ``class_interval``: the draws' means, or one draw's seeds in a study of one draw. NaN where
    that interval is a point (one value, no spread, one draw of several): no verdict."""
    groups = _groups(effects)
    if not groups or (study_draws >= 2 and len(groups) < 2):
        return math.nan
    x = np.array([g.mean() for g in groups]) if len(groups) >= 2 else groups[0]
    if x.size < 2 or _no_spread(x):
        return math.nan
    from statsmodels.stats.weightstats import DescrStatsW

    return float(DescrStatsW(x).ttost_mean(-margin, margin)[0])


def with_equivalence(said: str, p_equivalence: float, level: float = 0.95) -> str:
    """An undecided verdict becomes ``equivalent`` when the TOST rejects at 1 − ``level``."""
    if said == INCONCLUSIVE and math.isfinite(p_equivalence) and p_equivalence < 1.0 - level:
        return EQUIVALENT
    return said


def draws_needed(span: Interval, level: float = 0.95, power: float = 0.8, most: int = 100) -> str:
    """The training draws per model that would decide an effect with probability ``power`` at
    α = 1 − ``level`` if its true size were the one measured (``span``: an interval over draws),
    by the power of the one-sample t-test over the draws' effects (``statsmodels``); "> most"
    beyond ``most`` draws, ``NO_EFFECT`` when the measured effect is zero. Planning for the next
    study: adding draws until a row is decided would inflate its error rate (docs/study.md)."""
    if span.unit == POINT and span.replicates >= 2 and span.estimate == 0:
        return NO_EFFECT  # a tie in every draw and seed
    if span.unit == POINT and span.replicates >= 2:
        return "a spread first"  # equal effects in every draw: no power computation applies
    if span.unit != DRAWS or not span.sd > 0:
        return ""
    size = abs(span.estimate) / span.sd  # Cohen's d of the draws' effects
    if size < 1e-9:
        return NO_EFFECT
    from statsmodels.stats.power import TTestPower  # the scorecard's alone: imported here

    # the power at every whole number of draws, the first that reaches ``power`` (statsmodels'
    # own solve_power fails to converge for large effects, where the answer is 2 or 3 draws)
    draws = np.arange(2, most + 1)
    reached = np.flatnonzero(
        TTestPower().power(effect_size=size, nobs=draws, alpha=1.0 - level) >= power
    )
    return str(int(draws[reached[0]])) if reached.size else f"> {most}"


FDR_Q = 0.05
"""The false-discovery rate each setting's family of rows is held to (SPEC §10)."""


def fdr_verdicts(
    p_values: Sequence[float],
    verdicts: Sequence[str],
    q: float = FDR_Q,
    p_equivalence: Sequence[float] | None = None,
) -> list[str]:
    """Each row's verdict adjusted for the false-discovery rate over the family: a decided row
    (``holds`` or ``contradicted``) stays decided only if Benjamini–Hochberg at ``q`` rejects
    its null (``statsmodels.stats.multitest.multipletests``); the family is the rows with a
    p-value (a row without one, an exact row or an undecided one, keeps its verdict). An
    ``equivalent`` row stays so only if the same procedure over the rows' TOST p-values
    (``p_equivalence``) rejects its null of a difference of at least the margin."""
    from statsmodels.stats.multitest import multipletests

    out = list(verdicts)
    for values, kinds in ((p_values, (HOLDS, CONTRADICTED)), (p_equivalence, (EQUIVALENT,))):
        if values is None:
            continue
        tested = [i for i, p in enumerate(values) if p is not None and math.isfinite(p)]
        if not tested:
            continue
        reject = multipletests([values[i] for i in tested], alpha=q, method="fdr_bh")[0]
        for i, rejected in zip(tested, reject, strict=True):
            if out[i] in kinds and not rejected:
                out[i] = INCONCLUSIVE
    return out
