"""The question's stage for the rules: the runs of the stage `cape question` plans
(``question.plan``), with their solvers (``QUESTION`` in the rules)."""

from __future__ import annotations

from dataclasses import dataclass

from cape.specs import as_record
from cape.specs.question import StagePlan
from cape.study.question.plan import Plan, QuestionSettings, stage_runs
from cape.workflow.runs import Runs
from cape.workflow.start import refusals


@dataclass(frozen=True)
class QuestionRuns:
    """The question's settings and its current stage's plan (both None without a stage), and
    the grid's runs."""

    settings: QuestionSettings | None
    plan: StagePlan | None
    runs: Runs

    def targets(self) -> list[str]:
        """Every file of the runs the question's current stage names, with their solvers."""
        if self.settings is None or self.plan is None:
            return []
        with refusals():  # a stage.yaml edited by hand: its one line, not Snakemake's frames
            plan = Plan.from_config(as_record(self.plan))  # its seeds checked against its draws
        runs = [self.runs.grid.get(run, run) for run in stage_runs(self.settings, plan)]
        return [*self.runs.solver_outputs(runs), *self.runs.run_outputs(runs)]
