"""The ground-truth question in stages (SPEC §10, revision 6): its rows, what a look decides,
which models get more draws, and which runs a stage needs.

Rows: every pair of ``question.models`` on the five closed-loop metrics of
``cape.study.claims.question_claims``. Stage k gives every model of a row still open
``stages[k]`` trained draws; each row is decided by ``cape.study.sequential`` at the look of its
draws. ``cape question`` (cape/cli/question.py) drives Snakemake through the stages; this module
is the part of it that needs no Snakemake. Details: docs/modules.md.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from cape.study.question_plan import Row
from cape.study.scorecard import pair_effects, per_seed
from cape.study.sequential import INCONCLUSIVE, OPEN, SETTLED, Design, Look, look, seeds_per_draw
from cape.study.sequential import variance_components as components


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


def draw_values(runs: pd.DataFrame, row: Row, draws: int) -> list[float]:
    """The row's effect per training draw (the mean over its seeds, paired by seed), for the
    first ``draws`` draws of its models: a draw with no finite value is left out."""
    selected = row.claim.select(runs)
    per = per_seed(selected, row.claim) if len(selected) else {}
    effects = pair_effects(per, row.pair, row.claim)
    out = []
    for replicate in range(draws):
        values = [v for v in effects.get(replicate, []) if math.isfinite(v)]
        if values:
            out.append(float(np.mean(values)))
    return out


def evaluate(
    runs: pd.DataFrame, states: Sequence[RowState], design: Design, stage: int
) -> list[RowState]:
    """Look ``stage`` at every row still open: its decision from its draws' effects at the
    stage's draws. A row with fewer values than that (a draw untrained at the cap, or with no
    finite effect) cannot be looked at as planned: it is inconclusive for good, said in its
    ``why``, and buys no more draws. Decided rows keep their decision."""
    n = design.looks[stage]
    last = stage == len(design.looks) - 1
    nothing = (math.nan,) * 6
    for state in states:
        if state.done:
            continue
        values = draw_values(runs, state.row, n)
        if len(values) < n:
            why = f"{len(values)} of {n} draws have a value (a draw untrained, or no finite effect)"
            state.looks.append(Look(len(values), *nothing, INCONCLUSIVE, why))
            continue
        side = float(np.sign(state.row.pair.paper_effect))
        state.looks.append(look(values, design, state.row.margin, side, last))
    return list(states)


def next_draws(states: Iterable[RowState], current: Mapping[str, int], n: int) -> dict[str, int]:
    """Draws per model at the next look: ``n`` for every model of a row still open, the
    current number for the others (draws are added only where a row needs them)."""
    open_models = {m for s in states if not s.done for m in s.row.models}
    return {m: (max(n, d) if m in open_models else d) for m, d in current.items()}


def later_seeds(
    runs: pd.DataFrame,
    states: Sequence[RowState],
    draws: int,
    seeds: int,
    cost_ratio: float,
    least: int,
) -> tuple[int, pd.DataFrame]:
    """The seeds per later draw: each open row's two-stage optimum from its variance
    components over the first look's ``draws`` × ``seeds`` (``sequential.seeds_per_draw``; the
    cost of a draw over the cost of one seed's runs, ``cost_ratio``), then the median over the
    rows, rounded up. Returns it and the components per row (the report's)."""
    records = []
    for state in states:
        if state.done:
            continue
        row = state.row
        selected = row.claim.select(runs)
        effects = pair_effects(per_seed(selected, row.claim), row.pair, row.claim)
        table = [effects.get(r, [])[:seeds] for r in range(draws)]
        if any(len(t) < seeds for t in table) or seeds < 2:
            continue
        between, within = components(np.asarray(table, dtype=float)[None])
        n = seeds_per_draw(between, within, cost_ratio, least, seeds)
        records.append(
            {
                "claim": row.name,
                "comparison": row.comparison,
                "between_var": float(between[0]),
                "within_var": float(within[0]),
                "seeds": int(n[0]),
            }
        )
    frame = pd.DataFrame(
        records, columns=["claim", "comparison", "between_var", "within_var", "seeds"]
    )
    if frame.empty:
        return seeds, frame
    return math.ceil(float(frame["seeds"].median())), frame
