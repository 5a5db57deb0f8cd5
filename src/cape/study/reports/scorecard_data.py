"""What a scope's tables 8 and 9 are computed from, as one bundle they re-derive from.

``ScorecardData.from_results`` reads it from a results tree (the scorecard notebook does),
``write`` stores it as four small files (``cape.layout.paths.EVIDENCE_FILES``), ``read`` reads
them back (the notebook computes from what it read back, so nothing differs), and
``compute`` turns it into the tables. The notebook and ``cape replicates --from`` both call
``compute``, so a published folder re-derives exactly what the notebook wrote
(docs/study.md, "A published study").
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from cape.errors import CapeError
from cape.layout.paths import EVIDENCE_FILES as EVIDENCE
from cape.specs import as_record
from cape.specs.notebook import ScorecardSettings
from cape.specs.training import HealthSettings
from cape.storage.io import read_csv, read_json, write_bytes, write_text

LABELS = ("study", "model", "plant", "internal", "controller", "eta_label")
"""The runs' text columns (a label such as "2.5" is read back as text)."""
VALUE_COLUMNS = (*LABELS[:5], "replicate", "eta", "seed", "success", "eta_label", "lap_time",
                 "lap_time_penalised", "mean_abs_ex_penalised", "mean_abs_ey_penalised",
                 "mean_speed")  # fmt: skip
"""The columns of a run that tables 8 and 9 read (and table 5's best bicycle controller, whose
cells are aggregate.CELL)."""

FORMAT = "cape-scorecard-data/1"


@dataclass(frozen=True)
class About:
    """The settings and measured numbers tables 8 and 9 read besides the runs and draws."""

    models: tuple[str, ...]
    labels: Mapping[str, str]
    recipes: Mapping[str, str]
    paper: str
    ground_truth: str | None
    bicycle: tuple[str, ...]
    reference: str
    primary: str
    scorecard: Mapping[str, Any]
    health: Mapping[str, Any]
    ideal_lap_time: float | None
    replicates: tuple[int, ...]
    absent: str = ""


@dataclass
class ScorecardData:
    """Every run of the scope's paper, ground-truth and bicycle studies (``VALUE_COLUMNS``),
    tables 1 (``complexity``) and 4 (``openloop``) per draw, each draw's meta.json per
    (replicate, model), and ``about``."""

    runs: pd.DataFrame
    complexity: dict[int, pd.DataFrame]
    openloop: dict[int, pd.DataFrame]
    metas: dict[tuple[int, str], dict[str, Any]]
    about: About

    @classmethod
    def from_results(
        cls,
        job: Any,
        runs: pd.DataFrame,
        raceline: str,
        replicates: str | Sequence[int],
        complexity_paths: str | Sequence[str],
        openloop_paths: str | Sequence[str],
        model_root: str,
    ) -> ScorecardData:
        """The bundle of a results tree: ``job`` the notebook's spec (cape.specs.notebook),
        ``runs`` the scope's runs.parquet, and the notebook's other parameters."""
        from cape.closedloop.setup import load_reference
        from cape.study.claims.leaderboard import recipe
        from cape.study.inputs import read_draws, read_replicate_tables
        from cape.study.reports.notebook import nothing_here

        complexity = read_replicate_tables(replicates, complexity_paths, model_root)
        openloop = read_replicate_tables(replicates, openloop_paths, model_root)
        draws = sorted(openloop)
        models = tuple(job.models)
        studies = job.study.studies
        paper, truth = job.study.paper, job.study.ground_truth
        bicycle = tuple(s for s, grid in studies.items() if grid.kind == "bicycle")
        kept = runs[runs["study"].isin([paper, truth, *bicycle])]
        line, _ = load_reference(job.reference, raceline)
        about = About(
            models=models,
            labels=job.controller_labels(),
            recipes={m: recipe(entry) for m, entry in job.models.items()},
            paper=paper,
            ground_truth=truth if truth in studies else None,
            bicycle=bicycle,
            reference=job.study.reference_model,
            primary=job.study.primary_metric,
            scorecard=as_record(job.scorecard) if job.scorecard is not None else {},
            health=as_record(job.health) if job.health is not None else {},
            ideal_lap_time=float(line.ideal_lap_time()),
            replicates=tuple(draws),
            absent=nothing_here(runs.query("study == @paper"), job.study, paper),
        )
        values = kept[[c for c in VALUE_COLUMNS if c in kept]].reset_index(drop=True)
        return cls(values, complexity, openloop, read_draws(model_root, draws, models), about)

    def write(self, folder: str | Path) -> None:
        """The bundle's four files in ``folder`` (each written atomically)."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        write_bytes(folder / EVIDENCE[0], self.runs.to_csv(index=False).encode())
        tables = [
            t.assign(table=name, draw=r, columns="|".join(map(str, t.columns)))
            for name, per in (("complexity", self.complexity), ("openloop", self.openloop))
            for r, t in sorted(per.items())
        ]
        joined = pd.concat(tables, ignore_index=True) if tables else pd.DataFrame()
        write_bytes(folder / EVIDENCE[1], joined.to_csv(index=False).encode())
        metas = [{"replicate": r, "model": m, "meta": meta} for (r, m), meta in self.metas.items()]
        write_text(folder / EVIDENCE[2], json.dumps(metas, indent=1, default=str) + "\n")
        about = {"format": FORMAT, **asdict(self.about)}
        write_text(folder / EVIDENCE[3], json.dumps(about, indent=1, default=str) + "\n")

    @classmethod
    def read(cls, folder: str | Path) -> ScorecardData:
        """The bundle ``write`` stored in ``folder``, or one ``CapeError`` naming the file."""
        folder = Path(folder)
        fix = "give the evidence/ of a folder `cape replicates --publish` wrote, or publish again"
        if not folder.is_dir():
            raise CapeError(f"{folder}: no such folder; {fix}")
        damaged = "unreadable ({reason}); " + fix
        runs = read_csv(folder / EVIDENCE[0], fix, damaged, VALUE_COLUMNS[:9], text=LABELS)
        joined = read_csv(folder / EVIDENCE[1], fix, damaged, ("table", "draw", "columns"))
        per: dict[str, dict[int, pd.DataFrame]] = {"complexity": {}, "openloop": {}}
        for (name, draw), t in joined.groupby(["table", "draw"], sort=True):
            columns = str(t["columns"].iloc[0]).split("|")
            lacking = [c for c in columns if c not in t]
            if name not in per or lacking:
                raise CapeError(f"{folder / EVIDENCE[1]}: table {name!r} of draw {draw} is "
                                f"not one this bundle writes (lacks {lacking}); {fix}")  # fmt: skip
            per[str(name)][int(draw)] = t[columns].reset_index(drop=True)
        metas_path = folder / EVIDENCE[2]
        try:
            records = json.loads(metas_path.read_text())
            metas = {(int(x["replicate"]), str(x["model"])): dict(x["meta"]) for x in records}
        except FileNotFoundError:
            raise CapeError(f"{metas_path}: missing; {fix}") from None
        except (OSError, ValueError, TypeError, KeyError) as exc:
            raise CapeError(f"{metas_path}: not the draws' records ({exc}); {fix}") from None
        about = _about(read_json(folder / EVIDENCE[3], "a scorecard's evidence.json", fix),
                       folder / EVIDENCE[3], fix)  # fmt: skip
        return cls(runs, per["complexity"], per["openloop"], metas, about)


def _about(body: Mapping[str, Any], path: Path, fix: str) -> About:
    if body.get("format") != FORMAT:
        raise CapeError(f"{path}: format {body.get('format')!r}, not {FORMAT!r}; {fix}")
    try:
        lap = body["ideal_lap_time"]
        return About(
            models=tuple(str(m) for m in body["models"]),
            labels={str(k): str(v) for k, v in body["labels"].items()},
            recipes={str(k): str(v) for k, v in body["recipes"].items()},
            paper=str(body["paper"]),
            ground_truth=None if body["ground_truth"] is None else str(body["ground_truth"]),
            bicycle=tuple(str(s) for s in body["bicycle"]),
            reference=str(body["reference"]),
            primary=str(body["primary"]),
            scorecard=dict(body["scorecard"]),
            health=dict(body["health"]),
            ideal_lap_time=None if lap is None else float(lap),
            replicates=tuple(int(r) for r in body["replicates"]),
            absent=str(body.get("absent", "")),
        )
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise CapeError(f"{path}: not a scorecard's settings ({exc!r}); {fix}") from None


@dataclass
class Scorecard:
    """Tables 8 and 9 and what they rest on: the draws' health, the failed draws, every
    training tried, each model's reliability, table 5's best bicycle controllers, the claims'
    effects (figure 13) and one leaderboard per study shown (figure 14)."""

    health: pd.DataFrame
    failed: dict[int, dict[str, str]]
    trainings: pd.DataFrame
    reliability: pd.DataFrame
    best: pd.DataFrame
    table8: pd.DataFrame
    effects: pd.DataFrame
    boards: dict[str, pd.DataFrame] = field(default_factory=dict)
    table9: pd.DataFrame = field(default_factory=pd.DataFrame)


PAPER_TITLE = "learned plants (the paper's study)"
TRUTH_TITLE = "the ground-truth plant (the simulated true car)"


def compute(data: ScorecardData) -> Scorecard:
    """Tables 8 and 9 of ``data`` (cape.study.claims.scorecard, cape.study.claims.leaderboard)."""
    from cape.study.aggregate import summarise
    from cape.study.claims.declared import Context
    from cape.study.claims.leaderboard import leaderboard
    from cape.study.claims.scorecard import Evidence, evaluate_claims
    from cape.study.reports.notebook import nothing_table
    from cape.study.reports.tables import best_controller
    from cape.training.health import (
        draw_cap,
        draw_health,
        failed_draws,
        reliability_table,
        trainings_tried,
    )

    about, runs = data.about, data.runs
    health = draw_health(data.metas, float(about.health["outlier_factor"]))
    failed = failed_draws(health)
    trainings = trainings_tried(data.metas)
    reliability = reliability_table(
        trainings, HealthSettings.of(about.health), len(about.replicates), draw_cap(data.metas)
    )
    bicycle = runs[runs["study"].isin(list(about.bicycle)) & (runs["replicate"] == 0)]
    best = best_controller(summarise(bicycle), about.labels) if len(bicycle) else pd.DataFrame()
    context = Context(about.ideal_lap_time, failed, data.openloop)
    settings = ScorecardSettings.of(about.scorecard)
    paper_runs = runs[runs["study"] == about.paper]
    truth = about.ground_truth
    truth_runs = runs[runs["study"] == truth] if truth is not None else None
    evidence = Evidence(paper_runs, best, about.labels, data.complexity, data.openloop,
                        truth_runs, about.absent)  # fmt: skip
    table8, effects = evaluate_claims(evidence, context=context, settings=settings)
    shown = {PAPER_TITLE: paper_runs}
    if truth_runs is not None:
        shown[TRUTH_TITLE] = truth_runs
    boards = {
        title: leaderboard(
            study_runs,
            list(about.models),
            about.reference,
            about.primary,
            data.openloop,
            data.complexity,
            settings.power,
            settings.most_draws,
            failed=failed,
            reliability=reliability,
            margins=settings.margins,
            recipes=about.recipes,
        )
        for title, study_runs in shown.items()
    }
    if any(len(b) for b in boards.values()):
        table9 = pd.concat([b.assign(study=t) for t, b in boards.items() if len(b)],
                           ignore_index=True)  # fmt: skip
        table9 = table9[["study", *[c for c in table9.columns if c != "study"]]]
    else:
        table9 = nothing_table("no study of this target has runs of a learned model")
    return Scorecard(health, failed, trainings, reliability, best, table8, effects, boards,
                     table9)  # fmt: skip


NUMERIC_TOLERANCE = 1e-9
"""Relative difference a re-derived number may have from the published one (another CPU's
floating-point path); every word (verdicts, reasons) must be equal."""


def table_differences(derived: pd.DataFrame, published: pd.DataFrame, name: str) -> list[str]:
    """Where a re-derived table differs from the published one (as read from its CSV): each
    place named by table, row and column; numbers within ``NUMERIC_TOLERANCE``."""
    import io

    derived = pd.read_csv(io.StringIO(derived.to_csv(index=False)))  # as the CSV reads back
    if list(derived.columns) != list(published.columns) or len(derived) != len(published):
        return [
            f"{name}: the re-derived table has {len(derived)} rows × columns "
            f"{list(derived.columns)}, the published {len(published)} × {list(published.columns)}"
        ]
    out = []
    for i in range(len(derived)):
        for column in derived.columns:
            a, b = derived.at[i, column], published.at[i, column]
            if _same(a, b):
                continue
            label = derived.iloc[i, 0], derived.iloc[i, 1] if derived.shape[1] > 1 else ""
            out.append(f"{name} row {i + 1} {label}, {column}: published {b!r}, re-derived {a!r}")
    return out


def _same(a: Any, b: Any) -> bool:
    if pd.isna(a) and pd.isna(b):
        return True
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        a, b = float(a), float(b)
        if math.isinf(a) or math.isinf(b):
            return a == b
        return math.isclose(a, b, rel_tol=NUMERIC_TOLERANCE, abs_tol=1e-12)
    return str(a) == str(b)
