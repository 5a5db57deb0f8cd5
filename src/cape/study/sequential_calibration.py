"""How often the staged procedure errs: simulated questions at this study's sizes (SPEC §10).

A simulated row is what the question measures: training draws whose effects vary around the
true one with spread ``ratio`` (in units of the seeds' spread), each draw's seeds around its
draw, later draws with the seeds ``cape.study.sequential.seeds_per_draw`` chooses. The laws:
``normal``, ``skewed``, ``unequal``, ``failures``. Each function returns rates over ``trials``
seeded simulated rows. The laws in full: docs/modules.md; the table: docs/question.md; the
acceptance: tests/test_sequential.py.
"""

from __future__ import annotations

import math

import numpy as np

from cape.study.sequential import (
    CONTRADICTED,
    EQUIVALENT,
    HOLDS,
    Design,
    seeds_per_draw,
    simulate,
    variance_components,
)

LAWS = ("normal", "skewed", "unequal", "failures")
RUNS = 33
"""The runs a failure count is out of (3 NMPCs × 11 η)."""
BASE_FAILURES = 2.0
"""A model's mean failures per seed in the ``failures`` law."""


def _standard(law: str, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    if law == "normal":
        return rng.standard_normal(shape)
    sigma = 1.0
    mean, var = math.exp(sigma**2 / 2), (math.exp(sigma**2) - 1) * math.exp(sigma**2)
    return (np.exp(sigma * rng.standard_normal(shape)) - mean) / math.sqrt(var)


def seed_values(
    law: str,
    rng: np.random.Generator,
    trials: int,
    draws: int,
    seeds: int,
    ratio: float,
    effect: float,
) -> np.ndarray:
    """trials × draws × seeds simulated effects under ``law`` with a true mean ``effect``."""
    if law == "failures":
        base = BASE_FAILURES
        rate_a = rng.exponential(base + effect, size=(trials, draws, 1)) if base + effect > 0 else 0
        rate_b = rng.exponential(base, size=(trials, draws, 1))
        a = np.minimum(rng.poisson(np.broadcast_to(rate_a, (trials, draws, seeds))), RUNS)
        b = np.minimum(rng.poisson(np.broadcast_to(rate_b, (trials, draws, seeds))), RUNS)
        return (a - b).astype(float)
    if law not in LAWS:
        raise ValueError(f"unknown law {law!r}: one of {', '.join(LAWS)}")
    scale = 1 / math.sqrt(2)  # a − b of two models' values, each of this spread
    law_a, law_b = ("skewed", "normal") if law == "unequal" else (law, law)
    a = ratio * _standard(law_a, rng, (trials, draws, 1)) + _standard(
        law_a, rng, (trials, draws, seeds)
    )
    b = ratio * _standard(law_b, rng, (trials, draws, 1)) + _standard(
        law_b, rng, (trials, draws, seeds)
    )
    return effect + scale * (a - b)


def staged_draw_means(
    values: np.ndarray, first: int, cost_ratio: float, least: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """Each draw's effect as the procedure takes it: the first look's ``first`` draws averaged
    over all their seeds, every later draw over the seeds chosen from the first look's variance
    components (the two-stage optimum). Returns trials × draws means and each trial's seeds."""
    seeds = values.shape[-1]
    between, within = variance_components(values[:, :first, :])
    chosen = seeds_per_draw(between, within, cost_ratio, least, seeds)
    cumulative = np.cumsum(values, axis=-1)
    later = np.take_along_axis(cumulative[:, first:, :], (chosen - 1)[:, None, None], axis=-1)
    means = np.concatenate([values[:, :first, :].mean(axis=-1), later[..., 0] / chosen[:, None]], 1)
    return means, chosen


def run_rows(
    design: Design,
    law: str,
    effect: float,
    margin: float | None,
    ratio: float = 1.0,
    trials: int = 4000,
    seeds: int = 5,
    cost_ratio: float = 20.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``trials`` simulated rows through the procedure: decisions, draws used, seeds chosen."""
    rng = np.random.default_rng(seed)
    values = seed_values(law, rng, trials, design.looks[-1], seeds, ratio, effect)
    means, chosen = staged_draw_means(values, design.looks[0], cost_ratio)
    decisions, used = simulate(design, means, margin, side=1.0)
    return decisions, used, chosen


def false_verdict_rate(design: Design, law: str, ratio: float = 1.0, **kw) -> float:
    """With no true effect: the share of rows decided ``holds`` or ``contradicted``."""
    decisions, _, _ = run_rows(design, law, 0.0, kw.pop("margin", None), ratio, **kw)
    return float(np.isin(decisions, [HOLDS, CONTRADICTED]).mean())


def false_equivalence_rate(design: Design, law: str, margin: float, ratio: float = 1.0, **kw):
    """With a true effect equal to the margin: the share of rows called ``equivalent``."""
    decisions, _, _ = run_rows(design, law, margin, margin, ratio, **kw)
    return float((decisions == EQUIVALENT).mean())


def power(
    design: Design, law: str, effect: float, ratio: float = 1.0, margin: float | None = None, **kw
) -> tuple[float, float]:
    """With a true effect: the share decided on its side, and the mean draws used per model."""
    decisions, used, _ = run_rows(design, law, effect, margin, ratio, **kw)
    return float((decisions == HOLDS).mean()), float(used.mean())


def family_error(
    design: Design,
    law: str,
    null_rows: int,
    effect_rows: int,
    effect: float,
    margin: float | None,
    ratio: float = 1.0,
    trials: int = 2000,
    seed: int = 0,
    **kw,
) -> float:
    """Families of ``null_rows`` rows with no effect and ``effect_rows`` with ``effect``
    (|effect| ≥ margin): the share of families with at least one false verdict (a null row
    decided, a row with an effect called equivalent or decided the wrong way)."""
    nulls, _, _ = run_rows(design, law, 0.0, margin, ratio, trials * null_rows, seed=seed, **kw)
    real, _, _ = run_rows(
        design, law, effect, margin, ratio, trials * effect_rows, seed=seed + 1, **kw
    )
    false_null = np.isin(nulls, [HOLDS, CONTRADICTED]).reshape(trials, null_rows).any(axis=1)
    wrong = np.isin(real, [EQUIVALENT, CONTRADICTED]).reshape(trials, effect_rows).any(axis=1)
    return float((false_null | wrong).mean())
