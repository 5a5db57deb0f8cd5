"""Table 9, the leaderboard: where each learned model stands, in one study, over its training
draws and disturbance seeds (SPEC §9, §10).

One row per model of the study (every model of the grid, a new one included: nothing here names
a model). Each closed-loop metric is the model's value per (draw, seed), averaged over a draw's
seeds, with the Student-t interval over the draws (over the seeds with one draw:
cape.study.verdicts); beside them the model's open-loop RMSE and complexity (tables 4 and 1,
mean over draws) and its effect against the reference model on the primary metric, paired on
draw and seed, with a verdict (``lower``, ``higher`` or ``inconclusive``) and, when undecided,
the draws that would decide it. Rows are ranked by the primary metric (lowest first).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from cape.study.claims import FAILURES, NMPCS, Selection, at_eta, both, controllers
from cape.study.verdicts import INCONCLUSIVE, draws_needed, interval

LOWER, HIGHER = "lower", "higher"


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


def _span_text(values: Mapping[int, Sequence[float]]) -> tuple[float, str]:
    span = interval(values)
    if math.isnan(span.estimate):
        return math.nan, "–"
    if span.low == span.high:
        return span.estimate, f"{span.estimate:.3g}"
    return span.estimate, f"{span.estimate:.3g} [{span.low:.3g}, {span.high:.3g}]"


def leaderboard(
    runs: pd.DataFrame,
    models: Sequence[str],
    reference: str,
    primary: str,
    openloop: Mapping[int, pd.DataFrame] | None = None,
    complexity: Mapping[int, pd.DataFrame] | None = None,
    power: float = 0.8,
    most_draws: int = 100,
) -> pd.DataFrame:
    """Table 9 for one study's ``runs`` (every draw and seed; ``model``: the model the run is
    about): one row per model of ``models`` that has runs, ranked by ``primary``; see the module
    docstring. ``reference``: the model the effects are taken against."""
    runs = runs if "replicate" in runs else runs.assign(replicate=0)
    present = [m for m in models if m in set(runs["model"])]
    values = {metric.key: per_seed(runs, metric) for metric in METRICS}
    rows = []
    for model in present:
        row: dict[str, object] = {"model": model}
        for metric in METRICS:
            mine = {r: list(v) for (m, r), v in values[metric.key].items() if m == model}
            estimate, text = _span_text(mine)
            row[metric.label] = text
            if metric.key == primary:
                row["_rank"] = estimate
        for name, tables in (("openloop", openloop), ("complexity", complexity)):
            columns = OPENLOOP if name == "openloop" else COMPLEXITY
            for column in columns:
                found = [
                    float(t.set_index("model").loc[model, column])
                    for t in (tables or {}).values()
                    if model in set(t["model"]) and column in t
                ]
                row[column] = float(np.mean(found)) if found else math.nan
        row.update(_against(values[primary], model, reference, power, most_draws))
        rows.append(row)
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    table = table.sort_values("_rank", na_position="last", kind="stable")
    table.insert(0, "rank", range(1, len(table) + 1))
    return table.drop(columns=["_rank"]).reset_index(drop=True)


def _against(
    values: Mapping[tuple[str, int], pd.Series],
    model: str,
    reference: str,
    power: float,
    most_draws: int,
) -> dict[str, object]:
    """The primary metric's effect of ``model`` against ``reference``, paired on draw and seed:
    its interval, verdict and the draws needed when undecided."""
    nothing = {"effect vs reference": math.nan, "ci95_low": math.nan, "ci95_high": math.nan}
    if model == reference:
        return {**nothing, "verdict vs reference": "the reference", "draws needed": ""}
    effects = {}
    for (m, r), mine in values.items():
        if m != model or (reference, r) not in values:
            continue
        other = values[(reference, r)]
        common = mine.index.intersection(other.index)
        if len(common):
            effects[r] = list((mine[common] - other[common]).astype(float))
    span = interval(effects)
    if math.isnan(span.low):
        return {**nothing, "verdict vs reference": INCONCLUSIVE, "draws needed": ""}
    if span.contains_zero():
        said, needed = INCONCLUSIVE, draws_needed(span, 0.95, power, most_draws)
    else:
        said, needed = (LOWER if span.high < 0 else HIGHER), ""
    return {
        "effect vs reference": span.estimate,
        "ci95_low": span.low,
        "ci95_high": span.high,
        "verdict vs reference": said,
        "draws needed": needed,
    }
