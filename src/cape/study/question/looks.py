"""The ground-truth question in stages (SPEC §10, revision 6): its rows, what a look decides,
which models get more draws, and which runs a stage needs.

Rows: every pair of ``question.models`` on the five closed-loop metrics of
``cape.study.claims.declared.question_claims``. Stage k gives every model of a row still open
``stages[k]`` trained draws; each row is decided by ``cape.study.stats.sequential`` at the look
of its draws. ``cape question`` drives the stages through ``cape.study.question.run``; this
module is what a look decides. Details: docs/modules.md.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd

from cape.study.claims.scorecard import pair_effects, per_seed
from cape.study.question.plan import Row
from cape.study.stats.sequential import (
    FUTILE,
    INCONCLUSIVE,
    OPEN,
    SETTLED,
    Design,
    Look,
    components,
    look,
    settle_chance,
)


@dataclass
class RowState:
    """A row through the looks: each look's result, and its decision once settled."""

    row: Row
    looks: list[Look] = field(default_factory=list)

    @property
    def decision(self) -> str:
        return self.looks[-1].decision if self.looks else OPEN

    @property
    def settled(self) -> bool:
        return self.decision in SETTLED

    @property
    def done(self) -> bool:
        """Settled, or inconclusive for good (the cap, or a draw it lost)."""
        return self.decision != OPEN


PerSeed = Mapping[tuple[str, int], pd.Series]
"""(model, draw) → a claim's value per seed (``scorecard.per_seed``)."""
VALUE_COLUMNS = ["metric", "model", "draw", "seed", "value"]


def seed_values(runs: pd.DataFrame, rows: Sequence[Row]) -> dict[str, PerSeed]:
    """Each claim's value per (model, draw, seed) over ``runs``, by claim name: all a look
    reads (the rows' effects are paired differences of these)."""
    out: dict[str, PerSeed] = {}
    for row in rows:
        if row.name not in out:
            selected = row.claim.select(runs)
            out[row.name] = per_seed(selected, row.claim) if len(selected) else {}
    return out


def values_frame(values: Mapping[str, PerSeed]) -> pd.DataFrame:
    """``seed_values`` as one table (values.csv): metric (the claim's name), model, draw,
    seed, value."""
    records = [
        (name, model, int(draw), int(seed), float(v))
        for name, per in values.items()
        for (model, draw), series in sorted(per.items())
        for seed, v in series.items()
    ]
    return pd.DataFrame(records, columns=VALUE_COLUMNS)


def values_from_frame(frame: pd.DataFrame) -> dict[str, PerSeed]:
    """``values_frame``'s inverse."""
    out: dict[str, dict[tuple[str, int], pd.Series]] = {}
    for (name, model, draw), group in frame.groupby(["metric", "model", "draw"], sort=True):
        series = pd.Series(group["value"].to_numpy(float), index=group["seed"].to_numpy(int))
        out.setdefault(str(name), {})[(str(model), int(draw))] = series.sort_index()
    return out


def draw_table(values: Mapping[str, PerSeed], row: Row, draws: int) -> list[np.ndarray]:
    """The row's effects per training draw and seed (paired by seed; non-finite ones left out),
    for the first ``draws`` draws of its models: one array per draw, empty where it has none."""
    effects = pair_effects(values.get(row.name, {}), row.pair, row.claim)
    return [
        np.asarray([v for v in effects.get(r, []) if math.isfinite(v)], dtype=float)
        for r in range(draws)
    ]


def draw_values(runs: pd.DataFrame, row: Row, draws: int) -> list[float]:
    """The row's effect per training draw (the mean over its seeds, paired by seed), for the
    first ``draws`` draws of its models: a draw with no finite value is left out."""
    table = draw_table(seed_values(runs, [row]), row, draws)
    return [float(t.mean()) for t in table if t.size]


@dataclass(frozen=True)
class Spread:
    """A row's draws × seeds structure at a look: σ²_between draws, σ²_within a draw (pooled
    over its seeds; NaN where no draw has two seeds), the mean of 1/seeds over its draws, and
    the variance of its draws' mean effects (the t-test's)."""

    between: float
    within: float
    inverse_seeds: float
    variance: float

    @classmethod
    def of(cls, table: Sequence[np.ndarray]) -> Spread:
        sums = np.array([t.sum() for t in table])
        squares = np.array([(t**2).sum() for t in table])
        counts = np.array([t.size for t in table], dtype=float)
        between, within = components(sums, squares, counts)
        means = sums / counts
        variance = float(means.var(ddof=1)) if means.size > 1 else 0.0
        if not (counts > 1).any():  # no draw has two seeds: the seeds' spread is not measured
            within = math.nan
        return cls(float(between), float(within), float((1 / counts).mean()), variance)

    @property
    def floor(self) -> float:
        """The least variance a draw's effect has: its seeds' (``sequential.decide``; 0 where
        no draw has two seeds to measure them)."""
        return 0.0 if math.isnan(self.within) else self.within * self.inverse_seeds

    @property
    def seeds_share(self) -> float:
        """The share of a draw's effect variance its seeds make: σ²_w·mean(1/S) over that plus
        σ²_b (1: the draws differ by their seeds alone; NaN: no spread at all)."""
        total = self.between + self.floor
        return self.floor / total if total > 0 and not math.isnan(self.within) else math.nan

    def later(self, seeds: int) -> float:
        """The variance of a further draw's effect on ``seeds`` seeds (the draws' own variance
        where the seeds' is not measured)."""
        if math.isnan(self.within):
            return self.variance
        return self.between + self.within / seeds


def evaluate(
    values: Mapping[str, PerSeed] | pd.DataFrame,
    states: Sequence[RowState],
    design: Design,
    stage: int,
    most_seeds: int | None = None,
) -> list[RowState]:
    """Look ``stage`` at every row still open (``values``: ``seed_values``, or the runs they
    are taken from): its decision from its draws' effects at the
    stage's draws, their variance no less than their seeds' (``Spread.floor``). A row with fewer
    values than that (a draw untrained at the cap, or with no finite effect) cannot be looked at
    as planned: it is inconclusive for good, said in its ``why``, and buys no more draws. A row
    left open whose chance of settling by the cap, its later draws on ``most_seeds`` seeds
    (default: as many as its draws have), is below ``design.futility`` is ``FUTILE``. Decided
    rows keep their decision."""
    n = design.looks[stage]
    last = stage == len(design.looks) - 1
    nothing = (math.nan,) * 6
    if isinstance(values, pd.DataFrame):
        values = seed_values(values, [s.row for s in states])
    for state in states:
        if state.done:
            continue
        table = draw_table(values, state.row, n)
        means = [float(t.mean()) for t in table if t.size]
        if len(means) < n:
            why = f"{len(means)} of {n} draws have a value (a draw untrained, or no finite effect)"
            state.looks.append(Look(len(means), *nothing, INCONCLUSIVE, why))
            continue
        spread = Spread.of(table)
        side = float(np.sign(state.row.pair.paper_effect))
        found = look(means, design, state.row.margin, side, last, spread.floor)
        chance = math.nan
        if found.decision == OPEN:
            seeds = most_seeds or max(t.size for t in table)
            later = spread.later(seeds)
            margin = state.row.margin
            chance = float(settle_chance(found.estimate, spread.variance, n, later, design, margin))
            if design.futility > 0 and chance < design.futility:
                why = (
                    f"futile: its chance of settling by {design.cap} draws is {chance:.1%}, "
                    f"below {design.futility:.0%}"
                )
                found = replace(found, decision=FUTILE, why=why)
        state.looks.append(replace(found, chance=chance, spread=spread))
    return list(states)


def next_draws(states: Iterable[RowState], current: Mapping[str, int], n: int) -> dict[str, int]:
    """Draws per model at the next look: ``n`` for every model of a row still open, the
    current number for the others (draws are added only where a row needs them)."""
    open_models = {m for s in states if not s.done for m in s.row.models}
    return {m: (max(n, d) if m in open_models else d) for m, d in current.items()}


COMPONENT_COLUMNS = [
    "claim",
    "comparison",
    "between_var",
    "within_var",
    "seeds_share",
    "chance_next",
]


def payoff(
    states: Sequence[RowState],
    design: Design,
    stage: int,
    draws: Mapping[str, int],
    draw_cost: Mapping[str, float],
    seed_cost: float,
    least: int,
    most: int,
) -> tuple[int, pd.DataFrame]:
    """The seeds of the next stage's draws (``sequential.payoff_seeds``): of ``least`` …
    ``most``, the number that settles most open rows at the next look per CPU-second of the
    draws it buys (each model's ``draw_cost`` and ``seed_cost`` per seed's runs). Returns it,
    and per open row its spread and its chance of settling at the next look on that many."""
    from cape.study.stats.sequential import payoff_seeds

    n, ahead = design.looks[stage], stage + 1
    models = sorted({m for s in states if not s.done for m in s.row.models})
    alive = [s for s in states if not s.done and s.looks and s.looks[-1].spread is not None]
    if not models or not alive:
        return least, pd.DataFrame(columns=COMPONENT_COLUMNS)

    def chance(seeds: int) -> np.ndarray:
        out = []
        for s in alive:
            lk = s.looks[-1]
            later = lk.spread.later(seeds)
            out.append(
                float(
                    settle_chance(
                        lk.estimate, lk.spread.variance, n, later, design, s.row.margin, ahead
                    )
                )
            )
        return np.array([out])

    buying = np.array([[True] * len(models)])
    left = design.looks[ahead] - min(draws.get(m, n) for m in models)
    cost = np.array([draw_cost.get(m, math.nan) for m in models])
    seed = np.full(len(models), seed_cost)
    pick = int(payoff_seeds(chance, buying, left, cost, seed, least, most)[0])
    chances = chance(pick)[0]
    frame = pd.DataFrame(
        [
            {
                "claim": s.row.name,
                "comparison": s.row.comparison,
                "between_var": s.looks[-1].spread.between,
                "within_var": s.looks[-1].spread.within,
                "seeds_share": s.looks[-1].spread.seeds_share,
                "chance_next": float(c),
            }
            for s, c in zip(alive, chances, strict=True)
        ],
        columns=COMPONENT_COLUMNS,
    )
    return pick, frame


def next_seeds(
    states: Sequence[RowState],
    design: Design,
    stage: int,
    draws: Mapping[str, int],
    cost: Any,
    settings: Any,
    most: int,
) -> tuple[int, pd.DataFrame | None, str]:
    """The seeds of the next stage's draws, the open rows' components behind them, and a
    sentence saying how they were chosen: ``payoff`` at the measured costs (``cost``: a
    ``question_report.Cost``), within [``settings.least_seeds``, ``most``]; the study's seeds
    where a cost is not measured. ``question.seeds.least`` always holds, above the study's
    seeds or ``most`` too (it was lowered to them without a word: issue 61)."""
    least = settings.least_seeds
    per_draw = {m: cost.per_draw(m) for m in settings.models}
    per_seed = cost.per_seed()
    if not math.isfinite(per_seed) or any(not math.isfinite(c) for c in per_draw.values()):
        if least > settings.seeds:
            return least, None, (
                f"`question.seeds.least`'s {least}, above the study's {settings.seeds} (a cost "
                "is not measured)"
            )  # fmt: skip
        return settings.seeds, None, f"the study's {settings.seeds} (a cost is not measured)"
    most = max(most, least)  # a published stage's most (cape question --reuse) may be lower
    chosen, frame = payoff(states, design, stage, draws, per_draw, per_seed, least, most)
    said = (
        f"{chosen} for the draws after {design.looks[stage]}: of {least} … {most} (the most "
        f"a draw's training pays for: {per_seed:,.0f} s of runs a seed), the number that settles "
        "most open rows at the next look per CPU-second (docs/question.md)"
    )
    return chosen, frame, said
