"""Table 8: the paper's headline claims (SPEC §10) beside CAPE's, each with a three-valued
verdict per training replicate and pooled over them, and the measured cause of every verdict
that is not ``holds``.

A claim is tested as pairwise effects (an ordering EPM < DDM < DPM: EPM − DDM, EPM − DPM,
DDM − DPM; "EPM fewest failures": EPM − DDM, EPM − DPM), one row each. A closed-loop effect is
measured per (replicate, seed), pairing the models' runs of the same replicate index and
disturbance seed, and its interval is the two-level bootstrap of ``cape.study.verdicts``. An
open-loop error or an inference time is one value per replicate (the bootstrap over
replicates); a parameter count, a size or a FLOP count is the architecture's and exact.

Columns: ``claim``, ``comparison``, ``paper`` (the paper's effect), ``ours`` (our pooled
estimate, and the two models' values), ``ci95_low``/``ci95_high``, ``replicates``,
``verdict rep<r>`` per replicate, ``verdict`` (pooled), ``verdict trained`` (pooled over the
replicates whose trainings did not fail, SPEC §4), ``why``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from cape import paper
from cape.study.verdicts import (
    CONTRADICTED,
    HOLDS,
    INCONCLUSIVE,
    VERDICTS,
    combine,
    exact_verdict,
    interval,
    verdict,
)
from cape.tables import to_markdown

NMPCS = ("nmpc", "anmpc", "rnmpc")

NOT_RUN = "not run"
"""A replicate's verdict on a row measured in replicate 0 only (the bicycle study)."""

SPANS = "_spans"
"""A closed-loop row's intervals (per replicate and pooled), kept for figure 13."""

Effects = dict[int, list[float]]
"""Replicate → the effect's values (one per seed, or one for the replicate)."""


@dataclass
class Context:
    """What the ``why`` column draws on, all measured: the reference's ideal lap time, the
    trainings that failed (replicate → model → reason), the open-loop tables per replicate."""

    ideal_lap_time: float | None = None
    failed: Mapping[int, Mapping[str, str]] = field(default_factory=dict)
    openloop: Mapping[int, pd.DataFrame] = field(default_factory=dict)


def _per(runs: pd.DataFrame, value: pd.Series) -> dict[tuple[str, int], pd.Series]:
    """(model, replicate) → the value per seed."""
    frame = runs.assign(_value=value)
    out = {}
    for (model, replicate), group in frame.groupby(["model", "replicate"]):
        out[(str(model), int(replicate))] = group.groupby("seed")["_value"].mean()
    return out


def _pair_effects(
    per: Mapping[tuple[str, int], pd.Series],
    a: str,
    b: str,
    effect: Callable[[pd.Series, pd.Series], pd.Series],
) -> Effects:
    """Replicate → the effect of model ``a`` against ``b`` on their common seeds."""
    out: Effects = {}
    for (model, replicate), values in per.items():
        if model != a or (b, replicate) not in per:
            continue
        other = per[(b, replicate)]
        common = values.index.intersection(other.index)
        diff = effect(values[common], other[common])
        out[replicate] = [float(v) for v in diff if math.isfinite(v)]
    return out


def _mean_of(per: Mapping[tuple[str, int], pd.Series], model: str) -> float:
    values = [float(s.mean()) for (m, _), s in per.items() if m == model]
    return float(np.mean(values)) if values else math.nan


def _verdicts(
    effects: Effects, paper_sign: float, replicates: Sequence[int], trained: set[int]
) -> dict[str, Any]:
    """The interval pooled over every replicate, and the verdicts: per replicate, pooled and
    pooled over the replicates that trained."""
    pooled = interval(effects)
    row: dict[str, Any] = {
        "ci95_low": pooled.low,
        "ci95_high": pooled.high,
        "estimate": pooled.estimate,
        "replicates": pooled.replicates,
        SPANS: {"pooled": pooled},
    }
    for r in replicates:
        span = interval({r: effects[r]}) if r in effects else None
        row[f"verdict rep{r}"] = INCONCLUSIVE if span is None else verdict(span, paper_sign)
        if span is not None:
            row[SPANS][f"rep{r}"] = span
    row["verdict"] = verdict(pooled, paper_sign)
    kept = {r: v for r, v in effects.items() if r in trained}
    row["verdict trained"] = verdict(interval(kept), paper_sign) if kept else INCONCLUSIVE
    return row


def _trained(context: Context, models: Sequence[str], replicates: Sequence[int]) -> set[int]:
    """The replicates in which none of ``models`` failed to train."""
    return {r for r in replicates if not any(m in context.failed.get(r, {}) for m in models)}


def _failed_note(context: Context, models: Sequence[str]) -> str:
    """The failed trainings among ``models`` (their reasons are in table 4 and RESULTS.md)."""
    notes = []
    for m in models:
        reps = sorted(r for r, failed in context.failed.items() if m in failed)
        if reps:
            notes.append(f"{m.upper()} replicate {', '.join(map(str, reps))}")
    return f"training failed: {'; '.join(notes)}" if notes else ""


def _closed_loop_why(row: Mapping[str, Any], replicates: Sequence[int], extra: str) -> str:
    """What is measured about a closed-loop row that does not hold: whether the replicates
    disagree (the draw decides it) or each is within its seeds' spread, and ``extra``."""
    per = [row.get(f"verdict rep{r}", INCONCLUSIVE) for r in replicates]
    if row["verdict"] == INCONCLUSIVE:
        if len(set(per)) > 1:
            said = ", ".join(f"rep{r} {v}" for r, v in zip(replicates, per, strict=True))
            cause = f"the training draws disagree ({said})"
        else:
            cause = "within the spread of the seeds in every replicate"
    else:
        cause = "not explained"
    return f"{cause}; {extra}" if extra else cause


def _row(
    claim: str, comparison: str, paper_value: float | str, ours: str, verdicts: Mapping[str, Any]
) -> dict[str, Any]:
    return {
        "claim": claim,
        "comparison": comparison,
        "paper": paper_value,
        "ours": ours,
        **verdicts,
    }


def _sign(x: float) -> float:
    return float(np.sign(x))


def learned_claims(runs: pd.DataFrame, context: Context | None = None) -> list[dict]:
    """The closed-loop claims on the paper's study (``runs``: its runs, every replicate and
    seed; a ``replicate`` column, 0 when absent)."""
    context = context or Context()
    if runs.empty:
        return []
    runs = runs if "replicate" in runs else runs.assign(replicate=0)
    replicates = sorted(int(r) for r in runs["replicate"].unique())
    rows: list[dict] = []

    def add(
        claim: str,
        a: str,
        b: str,
        paper_a: float,
        paper_b: float,
        per: Mapping[tuple[str, int], pd.Series],
        effect,
        paper_effect: float,
        unit: str,
        why: Callable[[str], str],
    ) -> None:
        effects = _pair_effects(per, a, b, effect)
        if not effects:
            return
        trained = _trained(context, (a, b), replicates)
        v = _verdicts(effects, _sign(paper_effect), replicates, trained)
        values = f"{a.upper()} {_mean_of(per, a):.3g}, {b.upper()} {_mean_of(per, b):.3g}"
        ours = f"{v['estimate']:.3g}{unit} ({values})"
        row = _row(
            claim,
            f"{a.upper()} − {b.upper()}" if unit != " %" else f"{a.upper()} vs {b.upper()}",
            f"{paper_effect:.3g}{unit} ({a.upper()} {paper_a:g}, {b.upper()} {paper_b:g})"
            if unit != " %"
            else f"{paper_effect:+.3g} %",
            ours,
            v,
        )
        if row["verdict"] == HOLDS:
            row["why"] = ""
        else:
            notes = [n for n in (why(row["verdict"]), _failed_note(context, (a, b))) if n]
            row["why"] = _closed_loop_why(row, replicates, "; ".join(notes))
        row["_paper_effect"] = paper_effect
        rows.append(row)

    # 1. adaptive NMPC, failure-penalised lap time averaged over η
    adaptive = runs[runs["controller"] == "anmpc"]
    per = _per(adaptive, adaptive["lap_time_penalised"])
    order = ("epm", "ddm", "dpm")
    for a, b in itertools.combinations(order, 2):
        pa, pb = paper.ADAPTIVE_LAP_TIME[a], paper.ADAPTIVE_LAP_TIME[b]
        add(
            "adaptive NMPC lap time, penalised, mean over η (s): EPM < DDM < DPM",
            a,
            b,
            pa,
            pb,
            per,
            lambda x, y: x - y,
            pa - pb,
            " s",
            lambda v: _lap_time_note(context),
        )
    # 2. EPM against DPM and DDM at η = 1, averaged over the controllers
    at1 = runs[runs["eta"] == 1.0]
    if not at1.empty:
        for metric, anchors in paper.ETA1_RELATIVE.items():
            per = _per(at1, at1[metric])
            for other, value in anchors.items():
                add(
                    f"η = 1, mean over controllers: {metric} (%)",
                    "epm",
                    other,
                    math.nan,
                    math.nan,
                    per,
                    lambda x, y: 100 * (x - y) / y,
                    value,
                    " %",
                    lambda v: "",
                )
    # 3. NMPC-family failures over the η grid
    nmpc = runs[runs["controller"].isin(NMPCS)]
    total = len(nmpc[["controller", "eta"]].drop_duplicates())
    per = _fail_counts(nmpc)
    for other in ("ddm", "dpm"):
        pa, pb = paper.NMPC_FAILURES["epm"], paper.NMPC_FAILURES[other]
        add(
            f"NMPC-family failures of {total} runs: EPM fewest",
            "epm",
            other,
            pa,
            pb,
            per,
            lambda x, y: x - y,
            pa - pb,
            "",
            lambda v: "",
        )
    return rows


def _fail_counts(nmpc: pd.DataFrame) -> dict[tuple[str, int], pd.Series]:
    """(model, replicate) → failures per seed over the NMPC runs of the η grid."""
    fails = ~nmpc["success"].astype(bool)
    out = {}
    for (model, replicate), group in nmpc.assign(_f=fails).groupby(["model", "replicate"]):
        out[(str(model), int(replicate))] = group.groupby("seed")["_f"].sum().astype(float)
    return out


def _lap_time_note(context: Context) -> str:
    """Why our lap times are not the paper's: the reference's own ideal lap."""
    if context.ideal_lap_time is None:
        return ""
    return (
        f"our laps are bounded by the reference's ideal lap, {context.ideal_lap_time:.2f} s at "
        "its speed profile; the paper's 5.6–5.8 s lie below it"
    )


def bicycle_claims(best: pd.DataFrame, labels: Mapping[str, str]) -> list[dict]:
    """The best fixed-parameter bicycle controller per model (table 5 against the paper):
    replicate 0's bicycle study, a deterministic row (holds or contradicted)."""
    rows = []
    inverse = {v: k for k, v in labels.items()}
    for model, anchor in paper.BEST_BICYCLE.items():
        match = best[best["model"] == f"{model}-fixed"]
        if match.empty:
            continue
        r = match.iloc[0]
        ours = f"{r['best controller']}, η ≤ {r['max η completed']:g}, {r['lap time (s)']:.2f} s"
        same = inverse.get(r["best controller"], r["best controller"]) == anchor["controller"]
        name = labels.get(anchor["controller"], anchor["controller"])
        paper_text = f"{name}, η ≤ {anchor['max_eta']:g}, {anchor['lap_time']:.2f} s"
        v = HOLDS if same else CONTRADICTED
        rows.append(
            _row(
                "best bicycle controller (replicate 0)",
                f"{model.upper()} (fixed)",
                paper_text,
                ours,
                {
                    "replicates": 1,
                    "verdict rep0": v,
                    "verdict": v,
                    "verdict trained": v,
                    "why": "" if same else "not explained",
                },
            )
        )
    return rows


MODEL_ROWS = (
    # column of table 1 or 4, claim, table, deterministic (the architecture's) or measured
    ("params_M", "model complexity: parameters (M)", "complexity", True),
    ("size_MB", "model complexity: size (MB)", "complexity", True),
    ("flops_M", "model complexity: FLOPs (M)", "complexity", True),
    ("inference_ms", "model complexity: inference (ms)", "complexity", False),
    ("test_rmse_vx", "open-loop RMSE vx (ETHZMobil)", "openloop", False),
    ("test_rmse_vy", "open-loop RMSE vy (ETHZMobil)", "openloop", False),
    ("test_rmse_omega", "open-loop RMSE ω (ETHZMobil)", "openloop", False),
)


def _paper_model_value(column: str, model: str) -> float:
    if column.startswith("test_rmse_"):
        return paper.OPENLOOP_RMSE[model][column.removeprefix("test_rmse_")]
    return paper.COMPLEXITY[model][column]


def model_claims(
    complexity: Mapping[int, pd.DataFrame],
    openloop: Mapping[int, pd.DataFrame],
    context: Context | None = None,
) -> list[dict]:
    """Complexity and open-loop error, per pair in the paper's order: parameter counts, sizes
    and FLOPs are exact; inference times and errors vary over replicates (``complexity`` and
    ``openloop``: replicate → table 1 or table 4)."""
    context = context or Context()
    rows = []
    replicates = sorted(set(complexity) | set(openloop))
    for column, claim, table, exact in MODEL_ROWS:
        tables = complexity if table == "complexity" else openloop
        per = {r: t.set_index("model")[column] for r, t in tables.items()}
        models = [m for m in paper.COMPLEXITY if all(m in p.index for p in per.values())]
        if not per or len(models) < 2:
            continue
        paper_order = sorted(models, key=lambda m: _paper_model_value(column, m))
        label = f"{claim}: " + " < ".join(m.upper() for m in paper_order)
        for a, b in itertools.combinations(paper_order, 2):
            effects = {r: [float(p[a] - p[b])] for r, p in per.items()}
            mean_a = float(np.mean([p[a] for p in per.values()]))
            mean_b = float(np.mean([p[b] for p in per.values()]))
            pa, pb = _paper_model_value(column, a), _paper_model_value(column, b)
            if exact:
                value = effects[replicates[0]][0] if replicates else math.nan
                v = exact_verdict(value, -1.0)
                verdicts = {
                    "estimate": value,
                    "ci95_low": value,
                    "ci95_high": value,
                    "replicates": len(per),
                    "verdict": v,
                    "verdict trained": v,
                    **{f"verdict rep{r}": v for r in replicates},
                }
            else:
                trained = _trained(context, (a, b), replicates)
                verdicts = _verdicts(effects, -1.0, replicates, trained)
            row = _row(
                label,
                f"{a.upper()} − {b.upper()}",
                f"{pa - pb:.3g} ({a.upper()} {pa:g}, {b.upper()} {pb:g})",
                f"{verdicts['estimate']:.3g} ({a.upper()} {mean_a:.3g}, {b.upper()} {mean_b:.3g})",
                verdicts,
            )
            row["why"] = "" if row["verdict"] == HOLDS else _model_why(column, a, b, context)
            rows.append(row)
    return rows


def _model_why(column: str, a: str, b: str, context: Context) -> str:
    """The measured cause of a model row that does not hold."""
    if column == "inference_ms":
        return (
            "hardware and implementation: timed on this CPU with CAPE's compiled Φ, one window "
            "at a time; the paper's times come from another machine"
        )
    if column.startswith("test_rmse_"):
        component = column.removeprefix("test_rmse_")
        ratios = []
        for model in (a, b):
            values = [
                float(t.set_index("model").loc[model, f"test_rmse_{component}"])
                / float(t.set_index("model").loc[model, f"val_rmse_{component}"])
                for t in context.openloop.values()
                if model in set(t["model"]) and f"val_rmse_{component}" in t
            ]
            if values:
                ratios.append(f"{model.upper()} {np.mean(values):.1f}×")
        if ratios:
            return (
                "ETHZMobil extrapolation: the ETHZMobil error over the ETHZ validation error is "
                + ", ".join(ratios)
                + " (ETHZMobil's slip lies outside the training data's, SPEC §4.2)"
            )
    return "not explained"


def evaluate_claims(
    runs: pd.DataFrame,
    best_bicycle: pd.DataFrame,
    labels: Mapping[str, str],
    complexity: Mapping[int, pd.DataFrame] | pd.DataFrame | None = None,
    openloop: Mapping[int, pd.DataFrame] | pd.DataFrame | None = None,
    context: Context | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Table 8, every claim's rows (a table 1 or 4 given as one frame is replicate 0's), and
    the closed-loop rows' effects with their intervals per replicate and pooled (figure 13:
    claim, comparison, scope, estimate, low, high, paper)."""
    context = context or Context()
    if isinstance(complexity, pd.DataFrame):
        complexity = {0: complexity}
    if isinstance(openloop, pd.DataFrame):
        openloop = {0: openloop}
    if openloop and not context.openloop:
        context.openloop = openloop
    closed = learned_claims(runs, context)
    rows = closed + bicycle_claims(best_bicycle, labels)
    if complexity and openloop:
        rows += model_claims(complexity, openloop, context)
    effects = pd.DataFrame(
        [
            {
                "claim": r["claim"],
                "comparison": r["comparison"],
                "scope": scope,
                "estimate": span.estimate,
                "low": span.low,
                "high": span.high,
                "paper": r["_paper_effect"],
            }
            for r in closed
            for scope, span in r[SPANS].items()
        ],
        columns=["claim", "comparison", "scope", "estimate", "low", "high", "paper"],
    )
    table = pd.DataFrame([{k: v for k, v in r.items() if not k.startswith("_")} for r in rows])
    verdict_columns = sorted(c for c in table.columns if c.startswith("verdict rep"))
    first = ["claim", "comparison", "paper", "ours", "ci95_low", "ci95_high", "replicates"]
    order = first + verdict_columns + ["verdict", "verdict trained", "why"]
    for column in order:
        if column not in table:
            table[column] = "" if column.startswith("verdict") or column == "why" else math.nan
    table = table[order]
    # a row about replicate 0 alone (the bicycle study's) has no verdict in the others (a word
    # no CSV reader takes for a missing value, as it would "n/a")
    return table.fillna({c: NOT_RUN for c in verdict_columns}), effects


def claim_verdicts(table: pd.DataFrame, column: str = "verdict") -> pd.Series:
    """Per claim, its pairwise rows combined (``cape.study.verdicts.combine``)."""
    return table.groupby("claim", sort=False)[column].agg(lambda v: combine(list(v)))


def holds_everywhere(table: pd.DataFrame) -> pd.Series:
    """Rows that hold in every replicate they were measured in (``not run`` elsewhere)."""
    reps = [c for c in table.columns if c.startswith("verdict rep")]
    if not reps:
        return table["verdict"].eq(HOLDS)
    verdicts = table[reps]
    return verdicts.isin([HOLDS, NOT_RUN]).all(axis=1) & verdicts.eq(HOLDS).any(axis=1)


def counts(table: pd.DataFrame) -> dict[str, int]:
    """How many rows hold in every replicate, are contradicted in any, are inconclusive pooled."""
    reps = [c for c in table.columns if c.startswith("verdict rep")]
    every = holds_everywhere(table)
    anywhere = (
        table[reps].eq(CONTRADICTED).any(axis=1) if reps else table["verdict"].eq(CONTRADICTED)
    )
    return {
        "rows": len(table),
        "hold in every replicate": int(every.sum()),
        "contradicted in any replicate": int(anywhere.sum()),
        "inconclusive pooled": int(table["verdict"].eq(INCONCLUSIVE).sum()),
        **{f"pooled {v}": int(table["verdict"].eq(v).sum()) for v in VERDICTS},
    }


def at_a_glance(
    table: pd.DataFrame,
    runs: pd.DataFrame,
    health: pd.DataFrame | None = None,
    at_rest: tuple[pd.DataFrame, Sequence[str]] | None = None,
) -> str:
    """A one-page Markdown summary, written by the scorecard notebook to ``RESULTS.md``: first
    the claims that hold in every replicate, those contradicted, those inconclusive; then what
    ran, the trainings that failed, the laps without disturbances with the cause of every miss
    (``at_rest``: ``cape.study.undisturbed.undisturbed``), and every row with its verdicts and
    cause."""
    replicates = sorted(int(r) for r in runs["replicate"].unique()) if "replicate" in runs else [0]
    seeds = runs["seed"].nunique() if len(runs) else 0
    reps = [c for c in table.columns if c.startswith("verdict rep")]
    every = holds_everywhere(table)
    lines = [
        "# CAPE results at a glance",
        "",
        f"{len(runs)} closed-loop runs, training replicate(s) {', '.join(map(str, replicates))}, "
        f"{seeds} seed(s); table 8 (`table08_scorecard.md`). A verdict is `holds` when the 95 % "
        "interval of the effect lies wholly on the paper's side, `contradicted` when wholly on "
        "the other, `inconclusive` when it contains zero; pooled intervals resample the "
        "replicates, then the seeds within each (docs/study.md). Nothing is tuned toward the "
        "paper.",
        "",
    ]
    sections = (
        ("Holds in every replicate", every),
        ("Contradicted (pooled)", table["verdict"].eq(CONTRADICTED)),
        ("Inconclusive (pooled)", table["verdict"].eq(INCONCLUSIVE)),
        ("Holds pooled, not in every replicate", table["verdict"].eq(HOLDS) & ~every),
    )
    for title, mask in sections:
        lines += [f"## {title}: {int(mask.sum())} of {len(table)} rows", ""]
        for row in table[mask].itertuples(index=False):
            cause = f" — {row.why}" if row.why else ""
            lines.append(
                f"- {row.claim}, {row.comparison}: ours {row.ours}, paper {row.paper}{cause}"
            )
        lines.append("")
    if health is not None and len(health):
        failed = health[~health["trained"]]
        lines += ["## Trainings", ""]
        for model, group in health.groupby("model", sort=False):
            bad = group[~group["trained"]]
            lines.append(
                f"- {model.upper()}: {len(bad)} of {len(group)} replicate(s) failed to train"
                + "".join(f"; replicate {r.replicate}: {r.reason}" for r in bad.itertuples())
            )
        if failed.empty:
            lines.append("- every replicate trained")
        lines.append("")
    if at_rest is not None and len(at_rest[0]):
        grid, causes = at_rest
        lines += [
            "## Without disturbances (η = 0): laps per replicate and plant",
            "",
            to_markdown(grid),
            *(f"- {c}" for c in causes),
            *([""] if causes else []),
        ]
    lines += ["## Runs", "", "| study | runs | laps completed |", "|---|---|---|"]
    for study, group in runs.groupby("study", sort=False):
        lines.append(f"| {study} | {len(group)} | {group['success'].mean():.0%} |")
    lines += ["", "## Every row", ""]
    header = ["claim", "comparison", "paper", "ours", "95 % CI", *reps, "pooled", "trained", "why"]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in table.to_dict("records"):
        ci = "–" if pd.isna(row["ci95_low"]) else f"[{row['ci95_low']:.3g}, {row['ci95_high']:.3g}]"
        cells = [
            row["claim"],
            row["comparison"],
            row["paper"],
            row["ours"],
            ci,
            *(row[r] for r in reps),
            row["verdict"],
            row["verdict trained"],
            row["why"] or "",
        ]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines) + "\n"


def read_replicate_tables(paths: str | Sequence[str]) -> dict[int, pd.DataFrame]:
    """Replicate → table, from ``results/tables/rep<r>/<table>.csv`` paths (comma-separated in
    a notebook's parameter)."""
    import re
    from pathlib import Path

    items = paths.split(",") if isinstance(paths, str) else list(paths)
    tables = {}
    for item in (p for p in items if p):
        match = re.fullmatch(r"rep([0-9]+)", Path(item).parent.name)
        if match is None:
            raise ValueError(f"{item}: not a replicate's table (…/rep<r>/<table>.csv)")
        tables[int(match.group(1))] = pd.read_csv(item)
    return tables


def read_trainings(
    model_root: str, replicates: Sequence[int], models: Sequence[str]
) -> tuple[dict[tuple[int, str], pd.DataFrame], dict[tuple[int, str], float]]:
    """(replicate, model) → loss.csv and → meta.json's best validation loss, for the training
    checks of ``cape.models.health``."""
    import json
    from pathlib import Path

    losses, best = {}, {}
    for r in replicates:
        for m in models:
            folder = Path(model_root, f"rep{r}", m)
            losses[(r, m)] = pd.read_csv(folder / "loss.csv")
            best[(r, m)] = float(json.loads((folder / "meta.json").read_text())["best_val_loss"])
    return losses, best
