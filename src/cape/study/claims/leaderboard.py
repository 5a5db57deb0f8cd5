"""Table 9, the leaderboard: where each learned model stands, in one study, over its training
draws and disturbance seeds (SPEC §9, §10).

One row per model of the study (nothing here names a model), ranked by the primary metric
(lowest first) over the draws whose training worked; a model without a value of it is
``not evaluated`` and unranked. A row holds the closed-loop metrics with their intervals, the
open-loop RMSE and complexity, and the effect against the reference model with a verdict. A
point decides nothing. The columns: docs/modules.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from cape.study.claims.declared import FAILURES, NMPCS, Selection, at_eta, both, controllers
from cape.study.stats.verdicts import (
    EQUIVALENT,
    INCONCLUSIVE,
    POINT,
    Interval,
    UnusableEffectsError,
    class_interval,
    draws_needed,
    equivalence_p,
    with_equivalence,
)

LOWER, HIGHER = "lower", "higher"
NOT_EVALUATED = "not evaluated"
NO_REFERENCE = "no reference runs"


@dataclass(frozen=True)
class Metric:
    """One closed-loop column: the runs it reads, the per-run value (or ``FAILURES``) and how a
    seed's runs become one number (``mean`` or ``sum``)."""

    key: str
    label: str
    select: Selection
    column: str
    per_seed: str = "mean"


METRICS: tuple[Metric, ...] = (
    Metric("anmpc_lap_time", "adaptive NMPC lap time, penalised (s)", controllers(["anmpc"]),
           "lap_time_penalised"),
    Metric("nmpc_failures", "NMPC-family failures per seed", controllers(NMPCS), FAILURES, "sum"),
    Metric("ex_eta1", "η = 1 NMPCs' |e_x|, penalised (m)", both(at_eta(1.0), controllers(NMPCS)),
           "mean_abs_ex_penalised"),
    Metric("ey_eta1", "η = 1 NMPCs' |e_y|, penalised (m)", both(at_eta(1.0), controllers(NMPCS)),
           "mean_abs_ey_penalised"),
    Metric("speed_eta1", "η = 1 NMPCs' speed (m/s)", both(at_eta(1.0), controllers(NMPCS)),
           "mean_speed"),
)  # fmt: skip
"""The leaderboard's closed-loop columns (the claims' quantities, per model)."""

MARGIN_OF = {"anmpc_lap_time": "lap_time_penalised", "nmpc_failures": FAILURES}
"""The leaderboard metrics whose effect is in the unit of a ``scorecard.margins`` entry (the
others are absolute errors and speeds, whose margins are relative): their effect against the
reference can be ``equivalent``."""


def recipe(entry: Mapping[str, object]) -> str:
    """A model's training recipe in one phrase (SPEC §4: Adam, its rate, batch and epochs): which
    recipe made a row, as every table showing a DDM row must say (SPEC §4.2, revision 6)."""
    train = entry.get("train") or {}
    if not isinstance(train, Mapping):
        return ""
    return (
        f"Adam lr {float(train.get('lr', math.nan)):.3g}, batch {train.get('batch_size')}, "
        f"{train.get('epochs')} epochs"
    )


OPENLOOP = ("test_rmse_vx", "test_rmse_vy", "test_rmse_omega")
COMPLEXITY = ("params_M", "inference_ms")


def metric_of(key: str) -> Metric:
    """The metric named ``key`` (``study.primary_metric`` in the config)."""
    for metric in METRICS:
        if metric.key == key:
            return metric
    raise KeyError(f"{key}: not a leaderboard metric ({', '.join(m.key for m in METRICS)})")


def per_seed(runs: pd.DataFrame, metric: Metric) -> dict[tuple[str, int], pd.Series]:
    """(model, replicate) → the metric per seed over the runs it reads."""
    chosen = metric.select(runs)
    if chosen.empty:
        return {}
    value = (
        (~chosen["success"].astype(bool)).astype(float)
        if metric.column == FAILURES
        else chosen[metric.column].astype(float)
    )
    out = {}
    for (model, replicate), group in chosen.assign(_v=value).groupby(["model", "replicate"]):
        seeds = group.groupby("seed")["_v"]
        out[(str(model), int(replicate))] = (
            seeds.sum() if metric.per_seed == "sum" else seeds.mean()
        )
    return out


def _span(values: Mapping[int, Sequence[float]], study_draws: int) -> Interval | None:
    """``class_interval`` of ``values``; None where it refuses them (an infinite value, or
    values whose arithmetic overflows: a broken run, which the table says for what it is)."""
    try:
        return class_interval(values, study_draws)
    except UnusableEffectsError:
        return None


def _span_text(values: Mapping[int, Sequence[float]], study_draws: int) -> tuple[float, str]:
    span = _span(values, study_draws)
    if span is None:
        return math.nan, "not usable"
    if math.isnan(span.estimate):
        return math.nan, "–"
    if span.unit == POINT:
        return span.estimate, f"{span.estimate:.3g} ({span.why})"
    return span.estimate, f"{span.estimate:.3g} [{span.low:.3g}, {span.high:.3g}]"


def _unusable(
    runs: pd.DataFrame,
    metric: Metric,
    model: str,
    values: Mapping[tuple[str, int], pd.Series],
    study_draws: int,
) -> str:
    """Why ``model``'s values of ``metric`` (``values``: ``per_seed``) cannot rank it, or ""."""
    # A penalised lap time is at most the time limit or the penalty (SPEC §5.3): a value that is
    # infinite, or so large that the row's arithmetic (the mean over seeds and draws, the spread,
    # the interval) overflows to inf or NaN, is no lap time but a broken run. It is said for
    # what it is and the row left unranked: not "no value" (there is one), and not a failed lap
    # (counting the penalty would invent a failure the run did not record).
    if metric.column == FAILURES:
        return ""  # counts of failed runs: always finite
    mine = {r: list(v) for (m, r), v in values.items() if m == model}
    seeds = [v for vs in mine.values() for v in vs]
    if not np.isinf(seeds).any() and _span(mine, study_draws) is not None:
        return ""
    chosen = metric.select(runs)
    chosen = chosen[chosen["model"] == model]
    column = chosen[metric.column].astype(float)
    worst = column.abs().idxmax()
    value = float(column[worst])
    what = (
        "not a finite number"
        if math.isinf(value)
        else "its mean and spread over the seeds and draws overflow"
    )
    return (
        f"{metric.label}: {value:g} in draw {chosen.at[worst, 'replicate']}, seed "
        f"{chosen.at[worst, 'seed']} is not a usable value ({what}); a broken run: rerun it"
    )


def trained_runs(runs: pd.DataFrame, failed: Mapping[int, Mapping[str, str]]) -> pd.DataFrame:
    """The runs of the draws whose training worked (``failed``: replicate → model → reason, the
    draws that stood in for a model that reached its cap)."""
    if not failed or runs.empty:
        return runs
    drop = pd.Series(False, index=runs.index)
    for replicate, models in failed.items():
        drop |= (runs["replicate"] == replicate) & runs["model"].isin(list(models))
    return runs[~drop]


def leaderboard(
    runs: pd.DataFrame,
    models: Sequence[str],
    reference: str,
    primary: str,
    openloop: Mapping[int, pd.DataFrame] | None = None,
    complexity: Mapping[int, pd.DataFrame] | None = None,
    power: float = 0.8,
    most_draws: int = 100,
    failed: Mapping[int, Mapping[str, str]] | None = None,
    reliability: pd.DataFrame | None = None,
    margins: Mapping[str, float] | None = None,
    recipes: Mapping[str, str] | None = None,
) -> pd.DataFrame:
    """Table 9 for one study's ``runs`` (every draw and seed; ``model``: the model the run is
    about): one row per model of ``models`` that has runs, ranked by ``primary`` over the
    draws that trained (``failed``: the draws left out); see the module docstring.
    ``reference``: the model the effects are taken against; ``reliability``: per model, the
    trainings tried and the failure rate (cape.training.health.reliability_table). A model with
    no value of the primary metric is ``not evaluated`` and unranked; without the reference's
    runs every row says so."""
    runs = runs if "replicate" in runs else runs.assign(replicate=0)
    study_draws = int(runs["replicate"].nunique()) if len(runs) else 0
    present = [m for m in models if m in set(runs["model"])]  # a model whose draws all failed too
    runs = trained_runs(runs, failed or {})
    untrained = {m for m in present if m not in set(runs["model"])}
    values = {metric.key: per_seed(runs, metric) for metric in METRICS}
    unusable = {m: _unusable(runs, metric_of(primary), m, values[primary], study_draws)
                for m in present}  # fmt: skip
    has_reference = any(m == reference for m, _ in values[primary]) and not unusable.get(reference)
    rows = []
    for model in present:
        row: dict[str, object] = {"model": model}
        if recipes is not None:
            row["recipe"] = recipes.get(model, "")
        for metric in METRICS:
            mine = {r: list(v) for (m, r), v in values[metric.key].items() if m == model}
            estimate, text = _span_text(mine, study_draws)
            row[metric.label] = text
            if metric.key == primary:
                row["_rank"] = math.nan if unusable[model] else estimate
                row[metric.label] = "not usable" if unusable[model] else text
        for name, tables in (("openloop", openloop), ("complexity", complexity)):
            columns = OPENLOOP if name == "openloop" else COMPLEXITY
            for column in columns:
                found = [  # over the draws that trained, as the closed-loop columns
                    float(t.set_index("model").loc[model, column])
                    for r, t in (tables or {}).items()
                    if model in set(t["model"]) and column in t
                    and model not in (failed or {}).get(r, {})
                ]  # fmt: skip
                row[column] = float(np.mean(found)) if found else math.nan
        if reliability is not None and model in set(reliability["model"]):
            mine = reliability.set_index("model").loc[model]
            row["trainings (failed)"] = f"{int(mine['trainings tried'])} ({int(mine['failed'])})"
            row["failure rate"] = (
                f"{mine['failure rate']:.0%} [{mine['ci95_low']:.0%}, {mine['ci95_high']:.0%}]"
            )
        if math.isnan(float(row["_rank"])):
            label = metric_of(primary).label
            cause = (
                "none of its draws in this study trained (its trainings reached "
                "training.max_trainings)"
                if model in untrained
                else unusable[model]
                if unusable[model]
                else f"no value of the primary metric ({label}) in this study's runs of the "
                "draws that trained"
            )
            row.update(_no_effect(NOT_EVALUATED, cause))
        elif not has_reference:
            worked = " whose training worked" if reference in untrained else ""
            cause = (
                f"{reference.upper()} (study.reference_model): {unusable[reference]}"
                if unusable.get(reference)
                else f"{reference.upper()} (study.reference_model) has no run of the primary "
                f"metric in this study{worked}"
            )
            row.update(_no_effect(NO_REFERENCE, cause))
        else:
            margin = (margins or {}).get(MARGIN_OF.get(primary, ""))
            row.update(
                _against(values[primary], model, reference, power, most_draws, study_draws, margin)
            )
        rows.append(row)
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    ranked = table["_rank"].notna()
    table = pd.concat(
        [table[ranked].sort_values("_rank", kind="stable"), table[~ranked]], ignore_index=True
    )
    ranks = [*range(1, int(ranked.sum()) + 1), *[None] * int((~ranked).sum())]
    table.insert(0, "rank", pd.array(ranks, dtype="Int64"))  # unranked: empty
    return table.drop(columns=["_rank"]).reset_index(drop=True)


def _no_effect(said: str, cause: str) -> dict[str, object]:
    """The effect columns of a row with no effect to measure: ``said`` and why."""
    return {
        "effect vs reference": math.nan, "ci95_low": math.nan, "ci95_high": math.nan,
        "verdict vs reference": said, "draws needed": "", "why": f"{said}: {cause}",
    }  # fmt: skip


def _against(
    values: Mapping[tuple[str, int], pd.Series],
    model: str,
    reference: str,
    power: float,
    most_draws: int,
    study_draws: int,
    margin: float | None = None,
) -> dict[str, object]:
    """The primary metric's effect of ``model`` against ``reference``, paired on draw and seed:
    its interval, verdict (a point decides nothing: ``why`` says why; ``equivalent`` when the
    two one-sided tests put it inside ±``margin``) and the draws needed when undecided."""
    nothing = {"effect vs reference": math.nan, "ci95_low": math.nan, "ci95_high": math.nan}
    if model == reference:
        return {**nothing, "verdict vs reference": "the reference", "draws needed": "", "why": ""}
    effects = {}
    for (m, r), mine in values.items():
        if m != model or (reference, r) not in values:
            continue
        other = values[(reference, r)]
        common = mine.index.intersection(other.index)
        if len(common):
            effects[r] = list((mine[common] - other[common]).astype(float))
    span = _span(effects, study_draws)
    if span is not None and math.isnan(span.estimate):
        why = f"no draw and seed in common with {reference.upper()}"
        return {**nothing, "verdict vs reference": INCONCLUSIVE, "draws needed": "", "why": why}
    if span is None:  # an inf never decides
        why = f"the effect against {reference.upper()} overflows (its values are too large)"
        return {**nothing, "verdict vs reference": INCONCLUSIVE, "draws needed": "", "why": why}
    if span.unit == POINT:
        said, needed, why = INCONCLUSIVE, draws_needed(span, 0.95, power, most_draws), span.why
    elif span.contains_zero():
        said, needed, why = INCONCLUSIVE, draws_needed(span, 0.95, power, most_draws), ""
    else:
        said, needed, why = (LOWER if span.high < 0 else HIGHER), "", ""
    if margin is not None and said == INCONCLUSIVE:
        said = with_equivalence(said, equivalence_p(effects, margin, study_draws))
        if said == EQUIVALENT:
            needed, why = "", f"no practical difference: within ±{margin:g}"
    fewer = (
        f"rests on {span.replicates} of the study's {study_draws} draws"
        if study_draws > 1 and span.replicates < study_draws
        else ""
    )
    return {
        "effect vs reference": span.estimate,
        "ci95_low": span.low,
        "ci95_high": span.high,
        "verdict vs reference": said,
        "draws needed": needed,
        "why": "; ".join(w for w in (why, fewer) if w),
    }
