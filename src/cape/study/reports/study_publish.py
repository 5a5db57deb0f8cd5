"""A study's claims and leaderboard, published and re-derivable (docs/study.md, "A published
study").

``publish`` copies a scope's RESULTS.md, tables 8 and 9, figures 13 and 14 and its evidence
folder (cape.study.reports.scorecard_data) into a folder and adds ``provenance.json``: the
commit, the config's digest, the machine, each model's draws with their training and
disturbance seeds, the trainings tried and failed, and the CPU of each stage. ``rederive``
recomputes tables 8 and 9 from the folder's evidence alone and ``differences`` compares them
with its tables.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from cape.errors import CapeError
from cape.layout import paths
from cape.storage.io import read_csv, write_text
from cape.study.reports.scorecard_data import (
    NUMERIC_TOLERANCE,
    ScorecardData,
    compute,
    table_differences,
)

__all__ = ["NUMERIC_TOLERANCE", "differences", "missing", "provenance", "publish", "rederive"]

TABLES = ("tables/table08_scorecard", "tables/table09_leaderboard")
"""The tables a published study re-derives (each as .csv, which is compared, and .md)."""
COPIED = ("RESULTS.md", *(f"{t}{ext}" for t in TABLES for ext in (".csv", ".md")),
          "figures/fig13_claim_effects.png", "figures/fig14_leaderboard.png",
          *(f"evidence/{name}" for name in paths.EVIDENCE_FILES))  # fmt: skip
"""What ``publish`` copies from a scope (the same names in the folder)."""
REQUIRED = (*(f"{t}.csv" for t in TABLES), *(f"evidence/{n}" for n in paths.EVIDENCE_FILES))


def missing(scope: str) -> list[str]:
    """What of ``COPIED`` the scope does not hold (its scorecard notebook has not run)."""
    return [name for name in COPIED if not Path(scope, name).is_file()]


def publish(scope: str, folder: Path, config: Mapping[str, Any]) -> list[str]:
    """Copy ``COPIED`` from ``scope`` into ``folder`` and write its provenance; the names
    written. The caller claims them first (cape.storage.ownership)."""
    lacking = [n for n in missing(scope) if n in REQUIRED]
    if lacking:
        raise CapeError(
            f"{scope}: nothing to publish ({', '.join(lacking)} missing); build it first "
            "(`snakemake --cores 2 replicates`)"
        )
    names = [n for n in COPIED if Path(scope, n).is_file()]
    for name in names:
        target = folder / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(Path(scope, name), target)
    record = provenance(config, ScorecardData.read(folder / "evidence"), scope)
    write_text(folder / paths.STUDY_PROVENANCE, json.dumps(record, indent=1, default=str) + "\n")
    return [*names, paths.STUDY_PROVENANCE]


def rederive(folder: Path) -> dict[str, pd.DataFrame]:
    """Tables 8 and 9 (as the notebook saves them) from ``folder``'s evidence alone."""
    from cape.study.claims.scorecard import presented

    card = compute(ScorecardData.read(folder / "evidence"))
    return {TABLES[0]: presented(card.table8), TABLES[1]: card.table9}


def differences(folder: Path, derived: Mapping[str, pd.DataFrame]) -> list[str]:
    """Every place where a re-derived table differs from the one published in ``folder``,
    those of a verdict first."""
    out = []
    for name, table in derived.items():
        path = folder / f"{name}.csv"
        published = read_csv(path, "publish the study again (cape replicates --publish)",
                             "unreadable ({reason})")  # fmt: skip
        out += table_differences(table, published, str(path))
    return sorted(out, key=lambda place: "verdict" not in place.split(": published")[0])


def provenance(config: Mapping[str, Any], data: ScorecardData, scope: str) -> dict[str, Any]:
    """What made the published tables: commit, config digest, machine, each model's draws with
    their training seeds (failed ones too) and disturbance seeds, and each stage's CPU."""
    from cape.specs.study import StudySpec
    from cape.study.question.publish import config_digest, draw_record, machine
    from cape.study.question.state import commit

    study = StudySpec.from_config(config)
    draws: dict[str, list[dict[str, Any]]] = {}
    for (r, model), meta in sorted(data.metas.items()):
        draws.setdefault(model, []).append(draw_record(r, meta, study.draw_seeds(r)))
    return {
        "published by commit": commit(),
        "config_sha256": config_digest(config),
        "machine": machine(),
        "scope": scope,
        "draws": draws,
        "trainings tried": {m: len(tried(ds)) for m, ds in draws.items()},
        "trainings failed": {
            m: sum(not ok for ok in tried(ds).values()) for m, ds in draws.items()
        },
        "runs in the evidence": len(data.runs),
        "stages": stage_costs(data, scope),
    }


def tried(draws: list[dict[str, Any]]) -> dict[int, bool]:
    """A model's trainings tried over its draws (each draw lists those it was chosen among):
    seed → whether it trained."""
    return {int(t["seed"]): bool(t["trained"]) for d in draws for t in d["trainings tried"]}


def stage_costs(data: ScorecardData, scope: str) -> dict[str, dict[str, Any]]:
    """CPU seconds per stage of the scope's study, from the rules' records: the trainings
    tried (cape.study.question.report.training_cpu), the solver builds and the rollouts (each
    run's timing.json), with the files not found counted."""
    from cape.layout.names import replicate_name
    from cape.layout.record import read_timing
    from cape.study.question.report import _cpu, training_cpu

    trainings = [0.0, 0, 0]
    seen = set()
    for (_, model), meta in data.metas.items():
        for t in (meta.get("draw") or {}).get("trainings", []):
            key = (model, int(t["seed"]))
            if key in seen:
                continue
            seen.add(key)
            tsv = Path(paths.benchmark("train", model, f"seed{key[1]}.tsv"))
            cpu = training_cpu(model, key[1], tsv)
            trainings[1 if cpu is not None else 2] += 1
            trainings[0] += cpu or 0.0
    solvers = [0.0, 0, 0]
    for tsv in Path(paths.BENCHMARKS, "solvers").glob("*/*/*.tsv"):
        if tsv.parent.parent.name in {replicate_name(r) for r in data.about.replicates}:
            cpu = _cpu(tsv)
            solvers[1 if cpu is not None else 2] += 1
            solvers[0] += cpu or 0.0
    rollouts = [0.0, 0, 0]
    runs = pd.read_parquet(paths.study_runs(scope)) if Path(paths.study_runs(scope)).is_file() \
        else pd.DataFrame()  # fmt: skip
    from cape.study.reports.notebook import run_dir

    for row in runs.to_dict("records"):
        try:
            phases = read_timing(run_dir(paths.RUNS, row)).get("job_s", {})
        except CapeError:
            rollouts[2] += 1
            continue
        rollouts[1] += 1
        rollouts[0] += sum(
            float(phases.get(k, 0.0)) for k in ("startup", "config", "build", "lap", "write")
        )
    return {
        name: {"cpu_s": round(v[0], 1), "jobs": v[1], "records missing": v[2]}
        for name, v in (
            ("trainings", trainings),
            ("solver builds", solvers),
            ("rollouts", rollouts),
        )
    }
