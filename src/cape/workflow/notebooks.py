"""The study's tables and notebooks for the rules: the files each notebook declares, what the
scorecard reads, the two scopes' summaries and the study's own target (``NOTEBOOKS`` in the
rules); a notebook rule's shell command (``run_notebook``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from cape.layout import paths
from cape.specs.study import StudySpec
from cape.study.reports.outputs import STUDY_NOTEBOOKS, WHOLE_STUDY_NOTEBOOKS, NotebookOutputs
from cape.study.stale import missing_runs
from cape.workflow.runs import Runs
from cape.workflow.trainings import Outputs, Trainings

TABLE_EXTS = (".csv", ".md", ".tex")
DECLARED: dict[str, NotebookOutputs] = {**STUDY_NOTEBOOKS, **WHOLE_STUDY_NOTEBOOKS}
"""Every notebook's declared figures, tables and config sections (cape.study.reports.outputs)."""
COMPLEXITY_TABLE, OPENLOOP_TABLE = "table01_model_complexity", "table04_openloop_rmse"


@dataclass(frozen=True)
class Notebooks:
    """The study (its studies and their kinds, the paper's study, the draws), the runs and
    trainings the notebooks read, with Snakemake's ``outputs``."""

    study: StudySpec
    runs: Runs
    trainings: Trainings
    outputs: Outputs

    @property
    def scopes(self) -> dict[str, list[int]]:
        """The study's two summaries: the default target's (replicate 0) and the `replicates`
        target's (every draw), each with its runs.parquet, table 8, RESULTS.md and scorecard."""
        return {
            paths.DEFAULT_SCOPE: [0],
            paths.REPLICATES_SCOPE: list(range(self.study.replicates)),
        }

    def studies_of_kind(self, kind: str) -> str:
        """A wildcard constraint: the studies of ``kind`` (a pattern matching none if none)."""
        names = [s for s, grid in self.study.studies.items() if grid.kind == kind]
        return "|".join(names) or "(?!)"

    @staticmethod
    def figures(notebook: str, folder: str, ext: str) -> list[str]:
        """The figures a notebook declares (cape.study.reports.outputs), as files in ``folder``."""
        return [f"{folder}/{name}{ext}" for name in DECLARED[notebook].figures]

    @staticmethod
    def tables(notebook: str, folder: str) -> list[str]:
        """The tables a notebook declares, as .csv, .md and .tex files in ``folder``."""
        return [f"{folder}/{name}{ext}" for name in DECLARED[notebook].tables for ext in TABLE_EXTS]

    def example_series(self, study: str) -> list[str]:
        """The time series the η = 0 figures of ``study`` draw (``Runs.example_series``)."""
        return self.runs.example_series(study)

    def scorecard_inputs(self, wildcards: Any) -> dict[str, list[str]]:
        """What the scorecard of a scope reads beyond its runs: tables 1 and 4 and the draws'
        metadata and loss curves, of each of the scope's draws."""
        replicates = self.scopes[wildcards.scope]
        return {
            "complexity": [paths.replicate_table(r, COMPLEXITY_TABLE) for r in replicates],
            "openloop": [paths.replicate_table(r, OPENLOOP_TABLE) for r in replicates],
            "models": [
                path
                for r in replicates
                for path in self.trainings.trained_models(r)
                if not path.endswith(paths.WEIGHTS)
            ],
        }

    def study_targets(self) -> list[str]:
        """Every table, figure and executed notebook of the default target's study and the
        aggregation they read: per study, the notebook of its kind and the failure map; the
        set-up notebook; the scorecard when the paper's study is in the grid."""
        scope = paths.DEFAULT_SCOPE
        targets = self.outputs("aggregate", scope=scope) + self.outputs("notebook_setup")
        for study, grid in self.study.studies.items():
            targets += self.outputs(f"notebook_{grid.kind}", study=study)
            targets += self.outputs("notebook_failures", study=study)
        if self.study.paper in self.study.studies:
            targets += self.outputs("notebook_scorecard", scope=scope)
        return targets

    def stale_summaries(self) -> list[str]:
        """A message for each scope's runs.parquet whose runs are not all there: the targets
        that name every file rebuild them and it; asked for alone it would stay as it is."""
        messages = []
        for scope, replicates in self.scopes.items():
            missing = missing_runs(paths.study_runs(scope), self.runs.rollout_targets(replicates))
            if missing:
                target = "all" if scope == paths.DEFAULT_SCOPE else "replicates"
                messages.append(
                    f"{paths.study_runs(scope)}: {len(missing)} of its runs are missing (e.g. "
                    f"{missing[0].parent}); `snakemake --cores 2 {target}` rebuilds them and it"
                )
        return messages


def run_notebook(arguments: str) -> str:
    """The shell command of a notebook rule: papermill runs it under a `.part.ipynb` name (it
    writes as it runs), nbconvert makes the HTML copy, and the notebook is renamed last, so an
    interrupted notebook never looks finished. A failed notebook's executed copy goes beside
    its log. Every path is quoted: a checkout may have spaces in its path."""
    return (
        "(papermill {input.notebook:q} {output.notebook:q}.part.ipynb --cwd . --no-progress-bar "
        + arguments
        + " > {log:q} 2>&1"
        " && jupyter nbconvert --to html {output.notebook:q}.part.ipynb"
        ' --output-dir "$(dirname {output.html:q})"'
        ' --output "$(basename {output.html:q} .html)"'
        " --HTMLExporter.preprocessors=cape.study.reports.notebook_html.ShortParameters"
        " >> {log:q} 2>&1"
        " && mv {output.notebook:q}.part.ipynb {output.notebook:q})"
        " || ((mv -f {output.notebook:q}.part.ipynb {log:q}.failed.ipynb 2> /dev/null"
        ' && echo "the notebook failed; its executed copy, with the failing cell: "'
        "{log:q}.failed.ipynb"
        " || echo 'the notebook failed before it ran (no executed copy); the messages above say"
        " why') >> {log:q}; exit 1)"
    )
