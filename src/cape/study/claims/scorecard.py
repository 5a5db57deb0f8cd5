"""Table 8: the claims of cape.study.claims.declared evaluated on a scope's runs and tables
(SPEC §10).

Each pairwise comparison is one row; its columns are ``cape.study.claims.table8``'s. With two
or more draws the row's verdict is about the model class (cape.study.stats.verdicts); with one
draw (the default target) it is about that draw's networks, and the table says so
(``presented``). A point is inconclusive unless its row is exact. How effects are paired and
what sits beside the verdict: docs/modules.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from cape.layout.names import PlantName, replicate_name
from cape.specs.notebook import ScorecardSettings
from cape.study.claims.declared import (
    BICYCLE,
    CLOSED_LOOP,
    FAILURES,
    GROUND_TRUTH,
    GROUND_TRUTH_CLAIMS,
    MODEL,
    PAPER_SETTING,
    BicycleClaim,
    ClosedLoopClaim,
    Context,
    ModelClaim,
    Pair,
)
from cape.study.claims.table8 import (
    NOT_RUN,
    ClaimRow,
    DrawResult,
    draw_verdicts,
    draws_of,
    frame,
    verdict_column,
)
from cape.study.stats.verdicts import (
    CONTRADICTED,
    EQUIVALENT,
    HOLDS,
    INCONCLUSIVE,
    VERDICTS,
    Interval,
    class_interval,
    draw_effects,
    draws_needed,
    equivalence_p,
    exact_verdict,
    fdr_verdicts,
    interval,
    verdict,
    with_equivalence,
)

__all__ = [
    "ClaimSet",
    "Context",
    "Evidence",
    "Settings",
    "counts",
    "draws_of",
    "evaluate_claims",
    "one_draw",
    "presented",
]

LEVEL = 0.95
"""The verdicts' interval (SPEC §10: 95 %)."""

NOT_EVALUATED = "not evaluated"
"""The verdict of a row the study cannot evaluate (no runs of the claim's controller, a model
absent): listed with its reason, never dropped."""

Effects = dict[int, list[float]]
"""Replicate → the effect's values (one per seed, or one for the draw)."""


Settings = ScorecardSettings
"""``draws needed``'s power and most draws and the margins (config ``scorecard``)."""


@dataclass(frozen=True)
class ClaimSet:
    """The claims table 8 evaluates: closed-loop claims on the paper's study, model claims on
    tables 1 and 4, the bicycle claim (None: none), and CAPE's own on the ground-truth plant."""

    closed_loop: Sequence[ClosedLoopClaim] = CLOSED_LOOP
    model: Sequence[ModelClaim] = MODEL
    bicycle: BicycleClaim | None = BICYCLE
    ground_truth: Sequence[ClosedLoopClaim] = GROUND_TRUTH_CLAIMS


@dataclass
class Evidence:
    """What table 8 is computed from: the paper's study's ``runs`` (every draw and seed), the
    ground-truth study's (None: no such rows), the best bicycle controller per model, the
    controllers' labels, tables 1 and 4 per draw, and ``absent``: why there is no run, if so."""

    runs: pd.DataFrame
    best_bicycle: pd.DataFrame = field(default_factory=pd.DataFrame)
    labels: Mapping[str, str] = field(default_factory=dict)
    complexity: Mapping[int, pd.DataFrame] = field(default_factory=dict)
    openloop: Mapping[int, pd.DataFrame] = field(default_factory=dict)
    ground_truth: pd.DataFrame | None = None
    absent: str = ""


@dataclass
class _Evaluation:
    replicates: Sequence[int]
    context: Context
    settings: Settings
    rows: list[ClaimRow]
    spans: list[dict]


def per_seed(runs: pd.DataFrame, claim: ClosedLoopClaim) -> dict[tuple[str, int], pd.Series]:
    """(model, replicate) → the claim's value per seed over the runs it reads."""
    value = (
        (~runs["success"].astype(bool)).astype(float)
        if claim.metric == FAILURES
        else runs[claim.metric]
    )
    frame = runs.assign(_value=value)
    out = {}
    for (model, replicate), group in frame.groupby(["model", "replicate"]):
        per = group.groupby("seed")["_value"]
        out[(str(model), int(replicate))] = (
            per.sum() if claim.per_seed == "sum" else per.mean()
        ).astype(float)
    return out


def pair_effects(
    per: Mapping[tuple[str, int], pd.Series], pair: Pair, claim: ClosedLoopClaim
) -> Effects:
    """Replicate → the effect of model a against b on their common seeds."""
    out: Effects = {}
    for (model, replicate), values in per.items():
        if model != pair.a or (pair.b, replicate) not in per:
            continue
        other = per[(pair.b, replicate)]
        common = values.index.intersection(other.index)
        diff = claim.effect.of(values[common], other[common])
        out[replicate] = [float(v) for v in diff if math.isfinite(v)]
    return out


def _both(pair: Pair, a: float, b: float) -> str:
    """The two models' own values, as ``ours`` prints them beside the effect."""
    return f"{pair.a.upper()} {a:.3g}, {pair.b.upper()} {b:.3g}"


def _trained(context: Context, pair: Pair, replicates: Sequence[int]) -> list[int]:
    """The draws in which neither model of the pair failed to train."""
    return [
        r for r in replicates if not any(m in context.failed.get(r, {}) for m in (pair.a, pair.b))
    ]


def _failed_note(context: Context, pair: Pair) -> str:
    """The pair's draws whose trainings failed (a model that reached training.max_trainings
    with fewer trained draws than the study has: its failed trainings stand in, flagged)."""
    notes = []
    for m in (pair.a, pair.b):
        reps = sorted(r for r, failed in context.failed.items() if m in failed)
        if reps:
            notes.append(f"{m.upper()} draw {', '.join(map(str, reps))}")
    if not notes:
        return ""
    return (
        f"training failed and reached the cap: {'; '.join(notes)} (left out of the verdict, "
        "kept in the verdict over every draw, failed trainings included)"
    )


def _verdicts(
    ev: _Evaluation, effects: Effects, pair: Pair, row: ClaimRow, margin: float | None = None
) -> dict[str, Interval]:
    """Fill ``row``'s interval and verdicts: the headline over the draws that trained (or this
    draw's seeds), per draw over its seeds, over every draw (failed trainings included), and
    the draws needed when undecided; returns the intervals by scope (figure 13)."""
    sign = float(np.sign(pair.paper_effect))
    kept = {r: effects[r] for r in _trained(ev.context, pair, ev.replicates) if r in effects}
    study = len(ev.replicates)
    headline = class_interval(kept, study, LEVEL)
    every = class_interval(effects, study, LEVEL)
    spans = {"pooled": headline}
    row.ci95_low, row.ci95_high, row.estimate = headline.low, headline.high, headline.estimate
    row.draws, row.p = headline.replicates, headline.p
    row.used = sorted(r for r in kept if draw_effects({r: kept[r]}))
    row.evidence = headline.why
    means = draw_effects(effects)
    for r in ev.replicates:
        span = interval({r: effects[r]}, LEVEL) if r in effects else None
        own = INCONCLUSIVE if span is None else verdict(span, sign)
        row.per_draw[r] = DrawResult(means.get(r, math.nan), own)
        if span is not None:
            spans[replicate_name(r)] = span
    row.verdict = verdict(headline, sign)
    row.verdict_all = verdict(every, sign)
    if margin is not None:  # no practical difference: TOST over the interval's own values
        row.margin = margin
        row.p_equivalence = equivalence_p(kept, margin, study)
        row.verdict = with_equivalence(row.verdict, row.p_equivalence, LEVEL)
        row.verdict_all = with_equivalence(
            row.verdict_all, equivalence_p(effects, margin, study), LEVEL
        )
    settings = ev.settings
    row.draws_needed = (
        draws_needed(headline, LEVEL, settings.power, settings.most_draws)
        if row.verdict == INCONCLUSIVE
        else ""
    )
    return spans


def _why(ev: _Evaluation, row: ClaimRow, pair: Pair, causes: Sequence[str]) -> str:
    """The measured cause of a row that does not hold: too little evidence, how the draws'
    verdicts stand, the claim's own causes and the failed trainings involved; and, for any
    row, how many of the study's draws it rests on when fewer than all."""
    used = row.used
    fewer = (
        f"rests on {len(used)} of the study's {len(ev.replicates)} draws"
        if len(ev.replicates) > 1 and 0 < len(used) < len(ev.replicates)
        else ""
    )
    if row.verdict == HOLDS:
        return fewer
    if row.verdict == EQUIVALENT:
        inside = f"no practical difference: the effect lies within ±{row.margin:g}"
        return "; ".join(c for c in (inside, fewer) if c)
    notes = [c for c in (fewer, *causes, _failed_note(ev.context, pair)) if c]
    counted = [r for r in ev.replicates if r in used] or list(ev.replicates)  # the interval's
    per = [row.per_draw[r].verdict if r in row.per_draw else INCONCLUSIVE for r in counted]
    evidence = row.evidence
    if row.verdict == INCONCLUSIVE and evidence:
        if evidence == "no values":
            cause = "no draw that trained has a value"
        elif row.ci95_low == row.ci95_high == 0:
            cause = f"{evidence}: a tie in every draw and seed"
        else:
            cause = f"{evidence}: no verdict without a spread"
    elif row.verdict == INCONCLUSIVE and len(ev.replicates) > 1:
        if len(set(per)) > 1:
            said = ", ".join(f"{replicate_name(r)} {v}" for r, v in zip(counted, per, strict=True))
            cause = f"the training draws disagree ({said})"
        elif per[0] != INCONCLUSIVE:
            cause = (
                f"every draw's own verdict is {per[0]}, but {row.draws} draws this far "
                "apart do not decide the class"
            )
        else:
            cause = "within the spread of the seeds in every draw"
    elif row.verdict == INCONCLUSIVE:
        cause = "within the spread of the seeds"
    else:
        cause = "not explained"
    return "; ".join([cause, *notes])


def _mean_over(per: Mapping[tuple[str, int], pd.Series], model: str, draws: Sequence[int]) -> float:
    """A model's value averaged over its seeds in each of ``draws``, then over those draws: the
    same draws as the row's interval."""
    values = [float(s.mean()) for (m, r), s in per.items() if m == model and r in draws]
    return float(np.mean(values)) if values else math.nan


def _not_evaluated(
    ev: _Evaluation,
    claim: str,
    comparison: str,
    paper: str,
    why: str,
    setting: str = PAPER_SETTING,
) -> None:
    """A row the study cannot evaluate: listed, with why, never dropped."""
    ev.rows.append(
        ClaimRow(
            claim,
            comparison,
            paper,
            setting=setting,
            per_draw={r: DrawResult(verdict=NOT_EVALUATED) for r in ev.replicates},
            verdict=NOT_EVALUATED,
            verdict_all=NOT_EVALUATED,
            why=f"{NOT_EVALUATED}: {why}",
        )
    )


def _closed_loop(ev: _Evaluation, runs: pd.DataFrame, claim: ClosedLoopClaim) -> None:
    selected = claim.select(runs)
    per = per_seed(selected, claim) if len(selected) else {}
    cells = len(selected[["controller", "eta"]].drop_duplicates()) if len(selected) else 0
    name = claim.name.format(cells=cells)
    for pair in claim.pairs:
        comparison = f"{pair.a.upper()}{claim.effect.joiner}{pair.b.upper()}"
        effects = pair_effects(per, pair, claim)
        if not any(effects.values()):
            missing = [m.upper() for m in (pair.a, pair.b) if not any(k[0] == m for k in per)]
            if len(selected) and not missing:
                why = f"no finite {claim.metric} effect on common seeds"
            else:
                whose = f" of {' or '.join(missing)}" if len(selected) else ""
                paper = claim.setting == PAPER_SETTING
                study = "the paper's study" if paper else "the ground-truth study"
                why = f"{study} has no {claim.select.what}{whose}"
            _not_evaluated(ev, name, comparison, pair.paper_text, why, claim.setting)
            continue
        row = ClaimRow(name, comparison, pair.paper_text, setting=claim.setting)
        spans = _verdicts(ev, effects, pair, row, ev.settings.margins.get(claim.metric))
        used = row.used
        values = _both(pair, _mean_over(per, pair.a, used), _mean_over(per, pair.b, used))
        row.ours = f"{row.estimate:.3g}{claim.unit} ({values})" if used else "–"
        row.why = _why(ev, row, pair, [cause(ev.context, pair) for cause in claim.causes])
        ev.rows.append(row)
        ev.spans += [
            {
                "claim": name,
                "comparison": row.comparison,
                "scope": scope,
                "estimate": s.estimate,
                "low": s.low,
                "high": s.high,
                "paper": pair.paper_effect,
            }
            for scope, s in spans.items()
            if len(ev.replicates) > 1 or scope != "pooled"  # one draw: its own interval alone
        ]


def _model(ev: _Evaluation, claim: ModelClaim, tables: Mapping[int, pd.DataFrame]) -> None:
    if not tables:
        return
    per = {r: t.set_index("model")[claim.column] for r, t in tables.items() if claim.column in t}
    source = "table 1" if claim.table == "complexity" else "table 4"
    for pair in claim.pairs:
        comparison = f"{pair.a.upper()} − {pair.b.upper()}"
        absent = [
            m.upper() for m in (pair.a, pair.b) if not all(m in p.index for p in per.values())
        ]
        if not per or absent:
            why = (
                f"{source} has no {claim.column}"
                if not per
                else f"{source} has no {' or '.join(absent)}"
            )
            _not_evaluated(ev, claim.name, comparison, pair.paper_text, why)
            continue
        effects = {r: [float(p[pair.a] - p[pair.b])] for r, p in per.items()}
        row = ClaimRow(claim.name, comparison, pair.paper_text)
        if claim.exact:
            value = effects[min(effects)][0]
            v = exact_verdict(value, float(np.sign(pair.paper_effect)))
            row.estimate = row.ci95_low = row.ci95_high = value
            row.draws, row.used, row.exact = len(per), sorted(per), True
            row.per_draw = {
                r: DrawResult(effects[r][0] if r in effects else math.nan, v) for r in ev.replicates
            }
            row.verdict = row.verdict_all = v
        else:
            _verdicts(ev, effects, pair, row)
        used = row.used
        mean_a = float(np.mean([p[pair.a] for r, p in per.items() if r in used] or [math.nan]))
        mean_b = float(np.mean([p[pair.b] for r, p in per.items() if r in used] or [math.nan]))
        row.ours = f"{row.estimate:.3g} ({_both(pair, mean_a, mean_b)})" if used else "–"
        row.why = _why(ev, row, pair, [cause(ev.context, pair) for cause in claim.causes])
        ev.rows.append(row)


def _bicycle(
    ev: _Evaluation, claim: BicycleClaim, best: pd.DataFrame, labels: Mapping[str, str]
) -> None:
    inverse = {v: k for k, v in labels.items()}
    for model, anchor in claim.best.items():
        name = labels.get(str(anchor["controller"]), str(anchor["controller"]))
        paper = f"{name}, η ≤ {anchor['max_eta']:g}, {anchor['lap_time']:.2f} s"
        fixed = str(PlantName("fixed", model))
        match = best[best["model"] == fixed] if "model" in best else best
        if match.empty:
            why = f"no run of {model.upper()}-fixed in a bicycle study of this target (replicate 0)"
            _not_evaluated(ev, claim.name, f"{model.upper()} (fixed)", paper, why)
            continue
        r = match.iloc[0]
        same = inverse.get(r["best controller"], r["best controller"]) == anchor["controller"]
        v = HOLDS if same else CONTRADICTED
        ours = f"{r['best controller']}, η ≤ {r['max η completed']:g}, {r['lap time (s)']:.2f} s"
        ev.rows.append(
            ClaimRow(
                claim.name,
                f"{model.upper()} (fixed)",
                paper,
                ours,
                draws=1,
                per_draw={0: DrawResult(verdict=v)},  # the bicycle study is replicate 0's
                verdict=v,
                verdict_all=v,
                exact=True,
                why="" if same else "not explained",
            )
        )


def evaluate_claims(
    evidence: Evidence,
    claims: ClaimSet = ClaimSet(),
    context: Context | None = None,
    settings: Settings | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Table 8 (``cape.study.claims.table8``) of ``claims`` on ``evidence``, and the closed-loop
    rows' intervals per draw and pooled (figure 13: claim, comparison, scope, estimate, low,
    high, paper). With no run, each closed-loop claim is a ``not evaluated`` row giving
    ``evidence.absent`` (why there is none) as its reason."""
    runs, ground_truth = evidence.runs, evidence.ground_truth
    complexity, openloop = dict(evidence.complexity), dict(evidence.openloop)
    context = context or Context(openloop=openloop)
    if openloop and not context.openloop:
        context = Context(context.ideal_lap_time, context.failed, openloop)
    runs = runs if "replicate" in runs else runs.assign(replicate=0)
    if ground_truth is not None and "replicate" not in ground_truth:
        ground_truth = ground_truth.assign(replicate=0)
    replicates = sorted(
        {int(r) for r in runs["replicate"].unique()} | set(complexity) | set(openloop)
    )
    ev = _Evaluation(replicates, context, settings or ScorecardSettings(), [], [])
    for claim in claims.closed_loop:
        if runs.empty:
            why = evidence.absent or "the paper's study has no runs"
            for pair in claim.pairs:
                comparison = f"{pair.a.upper()}{claim.effect.joiner}{pair.b.upper()}"
                _not_evaluated(ev, claim.name.format(cells=0), comparison, pair.paper_text, why)
        else:
            _closed_loop(ev, runs, claim)
    if ground_truth is not None:
        for claim in claims.ground_truth:
            if ground_truth.empty:
                for pair in claim.pairs:
                    comparison = f"{pair.a.upper()}{claim.effect.joiner}{pair.b.upper()}"
                    why = "the ground-truth study has no runs in this target"
                    name = claim.name.format(cells=0)
                    _not_evaluated(ev, name, comparison, pair.paper_text, why, claim.setting)
            else:
                _closed_loop(ev, ground_truth, claim)
    if claims.bicycle is not None:
        _bicycle(ev, claims.bicycle, evidence.best_bicycle, evidence.labels)
    for model_claim in claims.model:
        tables = complexity if model_claim.table == "complexity" else openloop
        _model(ev, model_claim, tables)
    table = frame(ev.rows, replicates)
    table["verdict FDR"] = _adjusted(table)
    columns = ["claim", "comparison", "scope", "estimate", "low", "high", "paper"]
    return table, pd.DataFrame(ev.spans, columns=columns)


def _adjusted(table: pd.DataFrame) -> pd.Series:
    """Each row's verdict adjusted for the false-discovery rate over its setting's rows
    (Benjamini–Hochberg, cape.study.stats.verdicts.fdr_verdicts); a row not evaluated stays so."""
    out = table["verdict"].copy()
    for _, rows in table.groupby("setting", sort=False):
        adjusted = fdr_verdicts(
            rows["p"].astype(float).tolist(),
            rows["verdict"].tolist(),
            p_equivalence=rows["p equivalence"].astype(float).tolist(),
        )
        out.loc[rows.index] = adjusted
    return out


def one_draw(table: pd.DataFrame) -> bool:
    """Whether a table 8 rests on one training draw (its verdicts are about those networks)."""
    return len(draws_of(table)) <= 1


def presented(table: pd.DataFrame) -> pd.DataFrame:
    """Table 8 as written and shown: with one draw its verdicts are "this training draw"'s (no
    per-draw or draws-needed columns); with several, the class verdict over the draws that
    trained (per row and FDR-adjusted) beside the verdict over every draw and each draw's
    verdict about its one network."""
    draws = draws_of(table)
    if "setting" in table and not table["setting"].eq(GROUND_TRUTH).any():
        table = table.drop(columns=["setting"])  # the paper's rows alone: no column to tell
    if len(draws) <= 1:
        keep = ["claim", "comparison", "paper", "ours", "ci95_low", "ci95_high", "p", "margin",
                "p equivalence", "verdict", "verdict FDR", "why"]  # fmt: skip
        keep = [c for c in ("setting", *keep) if c in table]
        return table[keep].rename(
            columns={
                "verdict": "verdict (this training draw)",
                "verdict FDR": "verdict FDR (this training draw)",
            }
        )
    renamed = {verdict_column(r): f"{verdict_column(r)} (this network)" for r in draws}
    renamed |= {
        "verdict": "verdict (draws that trained)",
        "verdict FDR": "verdict FDR (draws that trained)",
        "verdict all draws": "verdict (every draw, failed trainings included)",
    }
    return table.drop(columns=["estimate"]).rename(columns=renamed)


def holds_for_every_network(table: pd.DataFrame) -> pd.Series:
    """Rows whose verdict holds for every trained network they were measured on."""
    verdicts = draw_verdicts(table)
    return verdicts.isin([HOLDS, NOT_RUN]).all(axis=1) & verdicts.eq(HOLDS).any(axis=1)


def counts(table: pd.DataFrame) -> dict[str, int]:
    """How many rows hold, are contradicted, are inconclusive (over the draws that trained, or
    for this one draw), the same after the false-discovery-rate adjustment, and how many hold
    for every network or are contradicted for any."""
    reps = draws_of(table)
    kinds = (*VERDICTS, NOT_EVALUATED)
    out = {"rows": len(table), **{v: int(table["verdict"].eq(v).sum()) for v in kinds}}
    if "verdict FDR" in table:
        out |= {f"FDR {v}": int(table["verdict FDR"].eq(v).sum()) for v in VERDICTS}
    if len(reps) > 1:
        out["hold for every network"] = int(holds_for_every_network(table).sum())
        contradicted = draw_verdicts(table).eq(CONTRADICTED).any(axis=1)
        out["contradicted for any network"] = int(contradicted.sum())
    return out
