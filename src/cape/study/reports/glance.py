"""RESULTS.md: a scope's scorecard on one page, written by the scorecard notebook.

With several training draws it opens with the verdicts about the model classes (the t-interval
over the draws, SPEC §10) and what each undecided row would need; with one draw it says that
its verdicts are about those trained networks and where the class verdicts are built.
"""

from __future__ import annotations

from collections.abc import Sequence

import pandas as pd

from cape.layout import paths
from cape.storage.tables import number_formats, to_markdown
from cape.study.claims.declared import GROUND_TRUTH
from cape.study.claims.scorecard import NOT_EVALUATED, draws_of, holds_for_every_network, presented
from cape.study.reports.tables import plant_failures
from cape.study.stats.verdicts import CONTRADICTED, EQUIVALENT, HOLDS, INCONCLUSIVE

REPLICATES_COMMAND = "snakemake --cores 2 replicates"


def _bullets(table: pd.DataFrame, mask: pd.Series, needed: bool = False) -> list[str]:
    lines = []
    for row in table[mask].to_dict("records"):
        cause = f" — {row['why']}" if row["why"] else ""
        more = f"; draws needed: {row['draws needed']}" if needed and row["draws needed"] else ""
        said = f"{row['claim']}, {row['comparison']}: ours {row['ours']}, paper {row['paper']}"
        lines.append(f"- {said}{more}{cause}")
    return lines


def _two_settings(table: pd.DataFrame) -> list[str]:
    """Side by side: what holds on the learned plants (the paper's setting: its claims, with
    the model and bicycle rows) and what holds on the ground-truth plant (the simulated car
    with its true parameters, CAPE's own rows, when the scorecard has them)."""
    setting = table["setting"] if "setting" in table else pd.Series("paper", index=table.index)
    sets = [("paper", "The paper's claims (learned plants; models; bicycle)")]
    if setting.eq(GROUND_TRUTH).any():
        sets.append((GROUND_TRUTH, "On the ground-truth plant (CAPE's own)"))
    kinds = (HOLDS, CONTRADICTED, EQUIVALENT, INCONCLUSIVE, NOT_EVALUATED)
    lines = ["| rows | " + " | ".join(kinds) + " |", "|---" * (len(kinds) + 1) + "|"]
    for key, label in sets:
        verdicts = table.loc[setting.eq(key), "verdict"]
        cells = " | ".join(str(int(verdicts.eq(k).sum())) for k in kinds)
        lines.append(f"| {label}: {len(verdicts)} | {cells} |")
    if "verdict FDR" in table:
        lines += ["", "Adjusted for the false-discovery rate over each setting's rows "
                  "(Benjamini–Hochberg, q = 0.05):", "",
                  lines[0], lines[1]]  # fmt: skip
        for key, label in sets:
            verdicts = table.loc[setting.eq(key), "verdict FDR"]
            cells = " | ".join(str(int(verdicts.eq(k).sum())) for k in kinds)
            lines.append(f"| {label}: {len(verdicts)} | {cells} |")
    if len(sets) > 1:
        lines += [
            "",
            "On the ground-truth plant (the simulated car with its true parameters, SPEC §1) each "
            "learned model is the NMPCs' internal model: a row there holds when the paper's "
            "ordering carries over to that plant (no paper value; the interval says which way "
            "and how much).",
        ]
    return lines


def _intro(table: pd.DataFrame, runs: pd.DataFrame) -> list[str]:
    draws = draws_of(table)
    # per draw: each draw has seeds of its own (SPEC §10, revision 7); no column: one draw
    per_draw = runs.assign(_draw=runs.get("replicate", 0))
    seeds = int(per_draw.groupby("_draw")["seed"].nunique().max()) if len(runs) else 0
    own = ", each draw its own" if len(draws) > 1 else ""
    common = (
        f"{len(runs)} closed-loop runs of the paper's study, {seeds} disturbance seed(s) per "
        f"draw{own}; table 8 "
        "(`table08_scorecard.md`). A verdict is `holds` when the 95 % interval of the effect "
        "lies wholly on the paper's side, `contradicted` when wholly on the other, `equivalent` "
        "(no practical difference) when the two one-sided tests put it inside the margin its "
        "metric has (`scorecard.margins`, docs/question.md), `inconclusive` otherwise "
        "(docs/study.md). Nothing is tuned toward the paper."
    )
    if len(draws) <= 1:
        return [
            f"**One training draw (replicate {draws[0] if draws else 0}).** Every verdict here "
            "is about this training draw's networks, over the disturbance seeds: another training "
            "seed or another CPU draws other networks, and the verdict may change. For verdicts "
            f"about the model classes, over several draws, run `{REPLICATES_COMMAND}` "
            f"(`{paths.glance(paths.REPLICATES_SCOPE)}`).",
            "",
            common,
        ]
    return [
        f"**{len(draws)} training draws (replicates {', '.join(map(str, draws))}).** A verdict is "
        "about the model class: each draw's effect is averaged over its seeds, and the interval is "
        f"Student's t over the draws' effects, the draws whose training worked (a training that "
        "fails is replaced by the next seed; a draw that stood in at the cap is left out and the "
        "row says so). A point (one value, or values that do not vary) decides nothing. Each "
        "draw's own verdict, over its seeds, is a statement about that one trained network (the "
        "`rep<r>` columns).",
        "",
        common,
    ]


def at_a_glance(
    table: pd.DataFrame,
    runs: pd.DataFrame,
    health: pd.DataFrame | None = None,
    at_rest: tuple[pd.DataFrame, Sequence[str]] | None = None,
    leaderboard: pd.DataFrame | None = None,
    reliability: pd.DataFrame | None = None,
) -> str:
    """The page: the verdicts (over the draws, or for this one draw), what ran, the trainings
    that failed, the laps without disturbances with the cause of every miss (``at_rest``:
    ``cape.study.reports.undisturbed.undisturbed``), table 9 (``leaderboard``), each model's recipe
    reliability (``reliability``: cape.training.health.reliability_table) and every row of table
    8 as presented."""
    several = len(draws_of(table)) > 1
    scope = "over the training draws" if several else "for this training draw"
    lines = ["# CAPE results at a glance", "", *_intro(table, runs), ""]
    lines += [*_two_settings(table), ""]
    verdicts = table["verdict"]
    lines += [f"## Holds {scope}: {int(verdicts.eq(HOLDS).sum())} of {len(table)} rows", ""]
    lines += [*_bullets(table, verdicts.eq(HOLDS)), ""]
    lines += [
        f"## Contradicted {scope}: {int(verdicts.eq(CONTRADICTED).sum())} of {len(table)} rows",
        "",
    ]
    lines += [*_bullets(table, verdicts.eq(CONTRADICTED)), ""]
    equivalent = int(verdicts.eq(EQUIVALENT).sum())
    lines += [f"## No practical difference {scope}: {equivalent} of {len(table)} rows", ""]
    lines += [*_bullets(table, verdicts.eq(EQUIVALENT)), ""]
    lines += [
        f"## Inconclusive {scope}: {int(verdicts.eq(INCONCLUSIVE).sum())} of {len(table)} rows",
        "",
    ]
    if several:
        lines += [
            "Each undecided row gives the draws per model that would decide it with 80 % power at "
            "α = 0.05 if its true effect were the one measured (`draws needed`). That number plans "
            "the next study; adding draws until a row is decided would inflate its error rate.",
            "",
        ]
    lines += [*_bullets(table, verdicts.eq(INCONCLUSIVE), needed=several), ""]
    missing = verdicts.eq(NOT_EVALUATED)
    if missing.any():
        lines += [f"## Not evaluated: {int(missing.sum())} of {len(table)} rows", ""]
        lines += [
            *(
                f"- {r['claim']}, {r['comparison']}: {r['why']}"
                for r in table[missing].to_dict("records")
            ),
            "",
        ]
    if several:
        every = holds_for_every_network(table)
        lines += [
            f"Per network: {int(every.sum())} of {len(table)} rows hold for every trained network "
            "on its own seeds; a row can hold for each network and still be undecided for the "
            "class when the draws lie far apart.",
            "",
        ]
    if reliability is not None and len(reliability):
        lines += [
            "## Trainings: how often each recipe fails",
            "",
            "A draw is a training that works: each model's trainings are tried in seed order and "
            "a failed one is replaced by the next seed (`table04_trainings.md` lists every "
            "training with its reasons). The failure rate's interval is Clopper–Pearson's.",
            "",
            to_markdown(reliability, number_formats(reliability)),
            "",
        ]
    if health is not None and len(health):
        lines += ["## Draws", ""]
        for model, group in health.groupby("model", sort=False):
            bad = group[~group["trained"]]
            lines.append(
                f"- {model.upper()}: {len(group) - len(bad)} of {len(group)} draw(s) trained"
                + "".join(
                    f"; draw {r.replicate} (seed {r.seed}) stood in at the cap: {r.reason}"
                    for r in bad.itertuples()
                )
                + "".join(
                    f"; draw {r.replicate}: {r.outlier} (reported only)"
                    for r in group.itertuples()
                    if getattr(r, "outlier", "")
                )
            )
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
    if len(runs) and "plant" in runs:
        lines += [
            "",
            "A failed run is its plant's when a learned plant left the envelope of its training "
            "data (`plant_diverged`, SPEC §5.3); every failure still counts as a failed lap.",
            "",
            to_markdown(plant_failures(runs)),
        ]
    if leaderboard is not None and len(leaderboard) and "model" in leaderboard:
        lines += [
            "",
            "## Table 9: where each model stands",
            "",
            "Every model of the grid, ranked by the primary metric; its effect against the "
            "reference model on that metric, with its 95 % interval and verdict "
            "(`table09_leaderboard.md`, figure 14).",
            "",
            to_markdown(leaderboard, number_formats(leaderboard)),
        ]
    every_row = presented(table)
    lines += ["", "## Every row", "", to_markdown(every_row, number_formats(every_row))]
    return "\n".join(lines) + "\n"
