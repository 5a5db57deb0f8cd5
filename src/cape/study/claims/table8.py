"""Table 8's rows as a type: ``ClaimRow`` holds one row, with a mapping from each training draw
to its effect and verdict, and ``frame`` makes the table, the one place its columns are named:
``setting``, ``claim``, ``comparison``, ``paper``, ``ours``, ``ci95_low``, ``ci95_high``,
``estimate``, ``draws``, ``p``, ``margin``, ``p equivalence``, ``effect rep<r>`` and
``verdict rep<r>`` per draw, ``verdict``, ``verdict FDR``, ``verdict all draws``,
``draws needed``, ``why``. The table keeps its draws in ``DataFrame.attrs["draws"]``
(``draws_of``), so nothing reads them back out of column names. What the columns hold:
docs/modules.md.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import pandas as pd

from cape.layout.names import replicate_name
from cape.study.claims.declared import PAPER_SETTING

NOT_RUN = "not run"
"""A draw's verdict on a row measured in replicate 0 only (the bicycle study)."""

DRAWS_KEY = "draws"
"""The ``DataFrame.attrs`` entry holding the draws a table 8 was evaluated over."""


def effect_column(replicate: int) -> str:
    """The column of draw ``replicate``'s effect (its mean over seeds)."""
    return f"effect {replicate_name(replicate)}"


def verdict_column(replicate: int) -> str:
    """The column of draw ``replicate``'s own verdict (over its seeds: one trained network)."""
    return f"verdict {replicate_name(replicate)}"


@dataclass(frozen=True)
class DrawResult:
    """One draw's part of a row: its effect and its own verdict."""

    effect: float = math.nan
    verdict: str = NOT_RUN


@dataclass
class ClaimRow:
    """One pairwise comparison of a claim, evaluated. ``used``: the draws its interval rests
    on; ``evidence``: why its interval is a point, if it is one (neither is a column)."""

    claim: str
    comparison: str
    paper: str
    ours: str = "–"
    setting: str = PAPER_SETTING
    estimate: float = math.nan
    ci95_low: float = math.nan
    ci95_high: float = math.nan
    draws: float = math.nan
    p: float = math.nan
    margin: float = math.nan
    p_equivalence: float = math.nan
    per_draw: dict[int, DrawResult] = field(default_factory=dict)
    verdict: str = ""
    verdict_all: str = ""
    draws_needed: Any = ""
    why: str = ""
    exact: bool = False
    used: list[int] = field(default_factory=list)
    evidence: str = ""

    def draw_verdict(self, replicate: int) -> str:
        return self.per_draw.get(replicate, DrawResult()).verdict

    def record(self, replicates: Sequence[int]) -> dict[str, Any]:
        """The row as table 8's columns (``verdict FDR`` is filled over the whole table)."""
        return {
            "setting": self.setting,
            "claim": self.claim,
            "comparison": self.comparison,
            "paper": self.paper,
            "ours": self.ours,
            "ci95_low": self.ci95_low,
            "ci95_high": self.ci95_high,
            "estimate": self.estimate,
            "draws": self.draws,
            "p": self.p,
            "margin": self.margin,
            "p equivalence": self.p_equivalence,
            **{effect_column(r): self.per_draw.get(r, DrawResult()).effect for r in replicates},
            **{verdict_column(r): self.draw_verdict(r) for r in replicates},
            "verdict": self.verdict,
            "verdict FDR": "",
            "verdict all draws": self.verdict_all,
            "draws needed": self.draws_needed,
            "why": self.why,
        }


def frame(rows: Iterable[ClaimRow], replicates: Sequence[int]) -> pd.DataFrame:
    """Table 8 of ``rows`` evaluated over draws ``replicates``, its columns in order."""
    records = [row.record(replicates) for row in rows]
    columns = list(ClaimRow("", "", "").record(replicates))
    table = pd.DataFrame(records, columns=columns)
    table.attrs[DRAWS_KEY] = list(replicates)
    return table


def draws_of(table: pd.DataFrame) -> list[int]:
    """The training draws a table 8 was evaluated over: as ``frame`` recorded them, else (a
    table read back from its CSV, or concatenated) those whose verdict column it has."""
    if DRAWS_KEY in table.attrs:
        return list(table.attrs[DRAWS_KEY])
    return [r for r in range(len(table.columns)) if verdict_column(r) in table.columns]


def draw_verdicts(table: pd.DataFrame) -> pd.DataFrame:
    """Each draw's own verdict, one column per draw (in draw order)."""
    return table[[verdict_column(r) for r in draws_of(table)]]
