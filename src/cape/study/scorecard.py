"""Table 8: the paper's headline claims (SPEC §10) beside CAPE's figures, each with its 95 %
confidence interval over seeds and whether the paper's direction holds here.

Every figure is recomputed per seed first (a seed is one replicate of the whole grid), then
averaged over seeds with a Student-t interval, so the interval describes seed-to-seed spread.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping

import numpy as np
import pandas as pd

from cape import paper
from cape.study.aggregate import mean_ci

NMPCS = ("nmpc", "anmpc", "rnmpc")


def _row(claim: str, item: str, paper_value: float | str, values: np.ndarray | None,
         direction: str, holds: bool | None, ours: str | None = None) -> dict:  # fmt: skip
    if values is not None:
        mean, half, n = mean_ci(list(values))
        shown = f"{mean:.3g}" if ours is None else ours
    else:
        mean, half, n, shown = np.nan, np.nan, 0, ours or "–"
    return {
        "claim": claim,
        "item": item,
        "paper": paper_value,
        "ours": shown,
        "ours_mean": mean,
        "ci95": half,
        "seeds": n,
        "paper's direction": direction,
        "holds": {True: "yes", False: "no", None: "n/a"}[holds],
    }


def _ordered(values: Mapping[str, float], order: tuple[str, ...]) -> bool:
    return all(values[a] < values[b] for a, b in itertools.pairwise(order))


def learned_claims(runs: pd.DataFrame) -> list[dict]:
    """The closed-loop claims on the paper's study (``runs``: its runs, of every seed)."""
    rows: list[dict] = []
    learned = runs
    if learned.empty:
        return rows
    # 1. adaptive NMPC, failure-penalised lap time averaged over η
    adaptive = learned[learned["controller"] == "anmpc"]
    per_seed = adaptive.groupby(["model", "seed"])["lap_time_penalised"].mean()
    means = {}
    for model, value in paper.ADAPTIVE_LAP_TIME.items():
        if model in per_seed.index.get_level_values(0):
            seeds = per_seed.loc[model].to_numpy()
            means[model] = float(np.mean(seeds))
            rows.append(_row("adaptive NMPC lap time, penalised, mean over η (s)", model.upper(),
                             value, seeds, "EPM < DDM < DPM", None))  # fmt: skip
    holds = _ordered(means, ("epm", "ddm", "dpm")) if len(means) == 3 else None
    for r in rows:
        r["holds"] = {True: "yes", False: "no", None: "n/a"}[holds]
    # 2. EPM against DPM and DDM at η = 1, averaged over the controllers
    at1 = learned[learned["eta"] == 1.0]
    if not at1.empty:
        for metric, anchors in paper.ETA1_RELATIVE.items():
            avg = at1.groupby(["model", "seed"])[metric].mean()
            for other, value in anchors.items():
                if "epm" not in avg.index.get_level_values(
                    0
                ) or other not in avg.index.get_level_values(0):
                    continue
                epm, base = avg.loc["epm"], avg.loc[other]
                common = epm.index.intersection(base.index)
                rel = 100 * (epm[common] - base[common]) / base[common]
                mean = float(np.mean(rel))
                claim = f"η = 1, EPM vs {other.upper()}: {metric} (%)"
                rows.append(_row(claim, f"vs {other.upper()}",
                                 value, rel.to_numpy(), "negative" if value < 0 else "positive",
                                 bool(np.sign(mean) == np.sign(value))))  # fmt: skip
    # 3. NMPC-family failures over the η grid
    nmpc = learned[learned["controller"].isin(NMPCS)]
    fails = (~nmpc["success"]).groupby([nmpc["model"], nmpc["seed"]]).sum()
    counts = {}
    # the claim's denominator is the grid's (3 NMPCs × 11 η = 33 per seed), the same for
    # every model even while a study is still incomplete
    total = len(nmpc[["controller", "eta"]].drop_duplicates())
    for model, value in paper.NMPC_FAILURES.items():
        if model in fails.index.get_level_values(0):
            seeds = fails.loc[model].to_numpy(dtype=float)
            counts[model] = float(np.mean(seeds))
            rows.append(_row(f"NMPC-family failures of {total} runs", model.upper(), value, seeds,
                             "EPM fewest", None))  # fmt: skip
    if counts:
        fewest = min(counts, key=counts.get)
        holds = counts.get("epm") == counts[fewest] if "epm" in counts else None
        for r in rows[-len(counts) :]:
            r["holds"] = {True: "yes", False: "no", None: "n/a"}[holds]
    return rows


def bicycle_claims(best: pd.DataFrame, labels: Mapping[str, str]) -> list[dict]:
    """The best fixed-parameter bicycle controller per model (table 5 against the paper)."""
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
        rows.append(_row("best bicycle controller", f"{model.upper()} (fixed)", paper_text, None,
                         "same controller", same, ours))  # fmt: skip
    return rows


def model_claims(complexity: pd.DataFrame, openloop: pd.DataFrame) -> list[dict]:
    """Complexity and open-loop error: deterministic figures (one trained model each)."""
    rows = []
    c = complexity.set_index("model")
    for col, label in (("params_M", "parameters (M)"), ("size_MB", "size (MB)"),
                       ("flops_M", "FLOPs (M)"), ("inference_ms", "inference (ms)")):  # fmt: skip
        paper_order = sorted(paper.COMPLEXITY, key=lambda m: paper.COMPLEXITY[m][col])
        ours_order = sorted(c.index, key=lambda m: c.loc[m, col])
        for model in c.index:
            rows.append(_row(f"model complexity: {label}", model.upper(),
                             paper.COMPLEXITY[model][col], np.array([c.loc[model, col]]),
                             "order " + " < ".join(m.upper() for m in paper_order),
                             ours_order == paper_order))  # fmt: skip
    o = openloop.set_index("model")
    for comp in ("vx", "vy", "omega"):
        paper_order = sorted(paper.OPENLOOP_RMSE, key=lambda m: paper.OPENLOOP_RMSE[m][comp])
        ours_order = sorted(o.index, key=lambda m: o.loc[m, f"test_rmse_{comp}"])
        for model in o.index:
            rows.append(_row(f"open-loop RMSE {comp}", model.upper(),
                             paper.OPENLOOP_RMSE[model][comp],
                             np.array([o.loc[model, f"test_rmse_{comp}"]]),
                             "order " + " < ".join(m.upper() for m in paper_order),
                             ours_order == paper_order))  # fmt: skip
    return rows


def scorecard(runs: pd.DataFrame, best_bicycle: pd.DataFrame, labels: Mapping[str, str],
              complexity: pd.DataFrame | None = None,
              openloop: pd.DataFrame | None = None) -> pd.DataFrame:  # fmt: skip
    rows = learned_claims(runs) + bicycle_claims(best_bicycle, labels)
    if complexity is not None and openloop is not None:
        rows += model_claims(complexity, openloop)
    return pd.DataFrame(rows)


def at_a_glance(table: pd.DataFrame, runs: pd.DataFrame) -> str:
    """A one-page Markdown summary of the study from the scorecard: what ran, how many laps
    were completed per study, and for each of the paper's claims how many of its rows hold
    here, then every row. Written by the scorecard notebook to ``results/RESULTS.md``."""
    seeds = runs["seed"].nunique() if len(runs) else 0
    lines = [
        "# CAPE results at a glance",
        "",
        f"Generated by the study from its {len(runs)} closed-loop runs ({seeds} seed(s)) and the "
        "claims scorecard (table 8, `results/tables/table08_scorecard.md`). Confidence "
        "intervals are 95 % Student-t intervals over seeds; `holds` says whether the paper's "
        "direction holds here. Nothing is tuned toward the paper.",
        "",
        "## Runs",
        "",
        "| study | runs | laps completed |",
        "|---|---|---|",
    ]
    for study, group in runs.groupby("study", sort=False):
        lines.append(f"| {study} | {len(group)} | {group['success'].mean():.0%} |")
    lines += ["", "## The paper's claims", "", "| claim | rows | direction holds |"]
    lines.append("|---|---|---|")
    for claim, group in table.groupby("claim", sort=False):
        lines.append(f"| {claim} | {len(group)} | {(group['holds'] == 'yes').sum()} |")
    held = int((table["holds"] == "yes").sum())
    lines += ["", f"In all: the paper's direction holds for {held} of {len(table)} rows.", ""]
    lines += ["## Every row", "", "| claim | item | paper | ours | ± 95 % CI | holds |"]
    lines.append("|---|---|---|---|---|---|")
    for row in table.itertuples(index=False):
        ci = "–" if pd.isna(row.ci95) else f"{row.ci95:.3g}"
        lines.append(
            f"| {row.claim} | {row.item} | {row.paper} | {row.ours} | {ci} | {row.holds} |"
        )
    return "\n".join(lines) + "\n"
