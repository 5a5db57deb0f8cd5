"""The question's driver (SPEC §10, revision 6): stage by stage, what `cape question` does.

``QuestionRun`` reads the merged config and the record of earlier runs (results/question/
looks.json: a rerun resumes), then for each stage: ``next_stage`` plans it (the draws of every
model of a row still open, the seeds each draw index is given, the draws a published question
already holds), ``run`` writes its plan (results/question/stage.yaml) and has Snakemake run it,
and ``look`` decides every open row, chooses the next stage's draws and seeds, and writes the
looks, the record and the report. ``finish`` has the report's notebook drawn. Snakemake itself
is handed in (``cape.workflow.launch.Snakemake``): this floor runs no process of its own.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cape.config import merged_config
from cape.layout import paths
from cape.specs.study import StudySpec
from cape.storage.io import write_text
from cape.study.claims.leaderboard import recipe
from cape.study.question import report
from cape.study.question.looks import (
    RowState,
    evaluate,
    next_draws,
    next_seeds,
    seed_values,
    values_frame,
)
from cape.study.question.plan import Plan, QuestionSettings, run_overrides
from cape.study.question.publish import Published
from cape.study.question.state import QuestionState

Runner = Callable[[Sequence[str], Path, str, str], None]
"""Runs a Snakemake target with config files, its output to a log: (files, log, what, target)."""


@dataclass(frozen=True)
class Stage:
    """Stage ``index`` (0-based) as planned: its draws and seeds, and the overrides its
    plan writes to results/question/stage.yaml."""

    index: int
    plan: Plan
    overrides: dict[str, Any]


class QuestionRun:
    """One `cape question`: the stages from the first (or where a stopped run left off) to the
    one where every row is settled or the last look is taken."""

    def __init__(self, files: Sequence[str], reuse: str | None, snakemake: Runner,
                 project_cores: int) -> None:  # fmt: skip
        config = merged_config(files)
        self.files, self.snakemake, self.project_cores = list(files), snakemake, project_cores
        self.settings = settings = QuestionSettings.from_config(config, " + ".join(files))
        self.study = StudySpec.from_config(config)
        self.design = settings.design()
        self.states = [RowState(row) for row in settings.rows()]
        identity = settings.identity(dict(self.study.models))
        self.record = QuestionState.read(identity)  # refused: nothing changed
        self.published = _published(reuse, identity, self.record)
        self.draws = {m: settings.stages[0] for m in settings.models}
        self.seeds = [settings.seeds] * settings.stages[0]
        self.seeds_said = f"the study's {settings.seeds}"
        self.components: Any = None
        self.lines: list[dict[str, Any]] = []
        self.next_index, self.settled, self.tick = 0, False, 0.0
        self.started = time.perf_counter()

    @property
    def stage_files(self) -> list[str]:
        """The config files every stage's Snakemake reads: the question's, then the plan."""
        return [*self.files, paths.QUESTION_STAGE]

    def log(self, name: str) -> Path:
        return Path(paths.QUESTION, "logs", f"{name}.log")

    def outputs(self) -> list[Path]:
        """Every file the run writes (to be claimed before any work)."""
        stages = [self.log(f"stage{k + 1}") for k in range(len(self.settings.stages))]
        return [Path(p) for p in (paths.QUESTION_STAGE, paths.QUESTION_LOOKS,
                paths.QUESTION_STATE, paths.QUESTION_REPORT, paths.QUESTION_COMPONENTS,
                paths.QUESTION_VALUES, *stages, self.log("notebook"))]  # fmt: skip

    def opening(self) -> str:
        """What the run will do, in one line."""
        s = self.settings
        return (
            f"cape question: {len(self.states)} rows ({len(s.claims())} metrics × "
            f"{len(s.claims()[0].pairs)} pairs of {', '.join(s.models)}); looks at "
            f"{', '.join(map(str, s.stages))} draws per model; family-wise α {s.alpha:g} (each "
            f"row {self.design.per_row:.2g}, spent over the looks); futility below a "
            f"{s.futility:.0%} chance of settling"
        )

    def next_stage(self) -> Stage | None:
        """The next stage planned, or None once every row is settled or the last look taken."""
        if self.settled or self.next_index >= len(self.settings.stages):
            return None
        reused = frozenset() if self.published is None else self.published.reused(
            self.settings, self.draws, self.seeds)  # fmt: skip
        plan = Plan(dict(self.draws), tuple(self.seeds), reused)
        return Stage(self.next_index, plan, run_overrides(self.study, self.settings, plan))

    def dry_run(self, stage: Stage) -> str:
        """``stage``'s plan and the Snakemake command that would run it."""
        import yaml

        return (yaml.safe_dump(stage.overrides, sort_keys=False).rstrip() + "\n"
                "$ snakemake question --configfile " + " ".join(self.stage_files))  # fmt: skip

    def announced(self, stage: Stage) -> str:
        """The line that opens ``stage``: its draws and the seeds per draw."""
        return (
            f"stage {stage.index + 1}/{len(self.settings.stages)}: draws "
            + ", ".join(f"{m.upper()} {d}" for m, d in stage.plan.draws.items())
            + f"; seeds per draw {report.seed_runs(list(stage.plan.seeds))}"
        )

    def run(self, stage: Stage) -> None:
        """Write ``stage``'s plan and have Snakemake run it. Stopped or failed, its wall time so
        far is kept in the record, for the resumed run's report."""
        import yaml

        write_text(paths.QUESTION_STAGE, yaml.safe_dump(stage.overrides, sort_keys=False))
        k = stage.index
        self.tick = time.perf_counter()
        try:
            self.snakemake(self.stage_files, self.log(f"stage{k + 1}"), f"stage {k + 1}",
                           "question")  # fmt: skip
        except BaseException:
            wall = time.perf_counter() - self.tick + self.record.wall_before(k + 1)
            self.record.stopped[k + 1] = round(wall, 1)
            self.record.looks, self.record.seeds = self.lines, self.seeds
            write_text(paths.QUESTION_STATE, self.record.as_json())
            raise

    def look(self, stage: Stage) -> str:
        """Decide every open row at ``stage``'s look, choose the next stage's draws and seeds,
        and write the values, looks, record and report; the stage's summary line."""
        k, plan, settings = stage.index, stage.plan, self.settings
        values = self._values(plan)
        cost = report.costs(settings, plan)
        most = report.most_seeds(settings, cost)
        if self.published is not None:
            most = self.published.most(plan, k, most)
        evaluate(values, self.states, self.design, k, most)
        wall = time.perf_counter() - self.tick + self.record.wall_before(k + 1)
        self.record.stopped.pop(k + 1, None)
        following = self._choose_next(k, cost, most)
        line = report.stage_record(k, settings.stages[k], self.draws, self.states, cost, wall,
                                   self.seeds, most)  # fmt: skip
        if self.published is not None:
            line = self.published.as_published(line, plan, k)
        self.lines.append(line)
        summary = self._write(cost)
        self.settled = all(s.done for s in self.states)
        self.next_index = k + 1
        if not self.settled and following is not None:
            self.draws = following
        return f"stage {k + 1}: {summary}"

    def _values(self, plan: Plan) -> dict[str, Any]:
        """The stage's per-seed values (a published question's where its draws are reused),
        written to results/question/values.csv."""
        runs = report.read_stage_runs(self.settings, plan)
        values = {} if runs is None else seed_values(runs, self.settings.rows())
        if self.published is not None:
            values = self.published.merge(values, plan.reused)
        write_text(paths.QUESTION_VALUES, values_frame(values).to_csv(index=False))
        return values

    def _choose_next(self, k: int, cost: Any, most: int) -> dict[str, int] | None:
        """The next stage's draws (None after the last stage or once every row is settled),
        and its seeds in ``self.seeds``: a resumed run's own choice, else chosen now."""
        settings = self.settings
        if k + 1 >= len(settings.stages) or all(s.done for s in self.states):
            return None
        following = next_draws(self.states, self.draws, settings.stages[k + 1])
        planned = self.record.seeds[len(self.seeds) : settings.stages[k + 1]]
        if len(planned) == settings.stages[k + 1] - len(self.seeds):  # a resumed run's own
            chosen, self.components = planned[0], None
            self.seeds_said = "as this question's first run chose (looks.json)"
        else:
            chosen, self.components, self.seeds_said = next_seeds(
                self.states, self.design, k, self.draws, cost, settings, most
            )
        self.seeds = self.seeds + [chosen] * (settings.stages[k + 1] - len(self.seeds))
        return following

    def _write(self, cost: Any) -> str:
        """The looks, the record, the variance components and the report after a look; the
        report's summary line."""
        settings, states = self.settings, self.states
        self.record.looks, self.record.seeds = self.lines, self.seeds
        write_text(paths.QUESTION_LOOKS, report.looks_frame(states).to_csv(index=False))
        write_text(paths.QUESTION_STATE, self.record.as_json())
        if self.components is not None:
            write_text(paths.QUESTION_COMPONENTS, self.components.to_csv(index=False))
        later = self.seeds[-1]
        remaining = report.remaining(states, settings, self.draws, cost, later)
        walls = {
            c: report.projected_wall(states, settings, self.draws, cost, later, c)
            for c in dict.fromkeys((2, self.project_cores))
        }
        recipes = {m: recipe(self.study.models[m]) for m in settings.models}
        write_text(
            paths.QUESTION_REPORT,
            report.markdown(settings, self.design, states, self.lines, self.components,
                            self.seeds_said, remaining, walls, recipes,
                            report.further_draw(cost, settings, later)),
        )  # fmt: skip
        return report.summary_line(states, cost, all(s.done for s in states), remaining, walls)

    def finish(self) -> str:
        """Have the report's notebook drawn (figure 15, table 10); the closing line."""
        notebook = paths.scoped(paths.QUESTION, "notebooks", "question.ipynb")
        self.snakemake(self.stage_files, self.log("notebook"), "the report's notebook", notebook)
        wall = time.perf_counter() - self.started
        return (
            f"cape question: report in {paths.QUESTION_REPORT}, figure 15 and table 10 in "
            f"{notebook} ({wall:,.0f} s)"
        )


def _published(reuse: str | None, identity: dict[str, Any], record: QuestionState) -> Any:
    """``--reuse``: the published question to continue from (its design must be this one's);
    with no look of its own yet, the record takes the published seeds of each draw."""
    if not reuse:
        return None
    published = Published(Path(reuse), identity)
    if not record.looks and len(published.state.seeds) > len(record.seeds):
        record.seeds = list(published.state.seeds)
    return published
