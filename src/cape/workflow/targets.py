"""The study's workflow for the rules: one object per stage, built once from the validated
config and two functions of Snakemake's, and the targets that span the stages.

``StudyWorkflow.from_config`` takes ``outputs(rule, **wildcards)``, the files one job of a rule
writes, and ``health(model, seed)``, a training's health record through the checkpoint (its
outcome decides the draws). The rules read its stages by name (workflow/rules/common.smk):
``TRACKS`` (cape.workflow.tracks), ``TRAININGS`` (trainings), ``RUNS`` (runs), ``NOTEBOOKS``
(notebooks) and ``QUESTION`` (question_runs); each job's file comes from ``JOBS``
(job_files).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from cape.layout import paths
from cape.layout.names import plant_names
from cape.specs.question import StagePlan
from cape.specs.run import RolloutSettings
from cape.specs.study import StudySpec
from cape.specs.tracks import DataSettings, ReferenceSettings, TracksSpec
from cape.specs.training import TrainingSettings
from cape.study.grid import study_grid
from cape.study.question.plan import QuestionSettings
from cape.workflow.notebooks import Notebooks
from cape.workflow.question_runs import QuestionRuns
from cape.workflow.runs import Runs
from cape.workflow.start import SOURCE
from cape.workflow.tracks import TrackFiles
from cape.workflow.trainings import Health, Outputs, Trainings


@dataclass(frozen=True)
class StudyWorkflow:
    """The grid of a validated config and its stages: the tracks and data, the trainings and
    draws, the runs, the tables and notebooks, and the question."""

    study: StudySpec
    tracks: TrackFiles
    trainings: Trainings
    runs: Runs
    notebooks: Notebooks
    question: QuestionRuns
    outputs: Outputs

    @classmethod
    def from_config(
        cls, config: Mapping[str, Any], outputs: Outputs, health: Health
    ) -> StudyWorkflow:
        study = StudySpec.from_config(config)
        tracks = TrackFiles.of(
            TracksSpec.from_config(config),
            DataSettings.from_config(config),
            ReferenceSettings.from_config(config),
            RolloutSettings.from_config(config),
        )
        trainings = Trainings.of(study, TrainingSettings.from_config(config), outputs, health)
        runs = Runs(
            study, study_grid(study, SOURCE), tracks.train_track, tracks.raceline(), outputs
        )
        plan = StagePlan.from_config(config)
        settings = QuestionSettings.from_config(config, SOURCE) if plan else None
        return cls(
            study=study,
            tracks=tracks,
            trainings=trainings,
            runs=runs,
            notebooks=Notebooks(study, runs, trainings, outputs),
            question=QuestionRuns(settings, plan, runs),
            outputs=outputs,
        )

    def constraints(self) -> dict[str, str]:
        """The wildcards' patterns."""
        names = plant_names(self.trainings.models)
        return {
            "track": "|".join(self.tracks.tracks),
            "model": "|".join(self.trainings.models),
            "study": "|".join(sorted(self.study.studies)),
            "plant": "|".join(names),
            "internal": "|".join(names),
            "controller": "|".join(sorted(self.study.controllers)),
            "eta": r"[0-9]+(\.[0-9]+)?",
            "seed": r"[0-9]+",
            "training_seed": r"[0-9]+",
            "replicate": r"[0-9]+",
            "scope": "|".join(self.notebooks.scopes),
        }

    def all_targets(self) -> list[str]:
        """The default target: every file the workflow makes for draw 0."""
        runs = self.runs.computed_runs({0})
        return [
            *self.outputs("tracks"),
            *(path for t in self.tracks.data_tracks for path in self.outputs("dataset", track=t)),
            *self.outputs("figure_tracks"),
            *self.trainings.model_outputs([0]),
            *self.outputs("figure_models"),
            *self.outputs("raceline", track=self.tracks.reference_track),
            *self.runs.solver_outputs(runs),
            *self.runs.run_outputs(runs),
            *self.notebooks.study_targets(),
        ]

    def replicate_targets(self) -> list[str]:
        """The `replicates` target: every draw's models and the paper's study for each, with
        its scorecard under results/replicates/, and every file those are made from."""
        if self.study.paper not in self.study.studies:
            return []
        runs = self.runs.computed_runs()
        return [
            *self.trainings.model_outputs(range(self.study.replicates)),
            *self.runs.solver_outputs(runs),
            *self.runs.run_outputs(runs),
            *self.outputs("aggregate", scope=paths.DEFAULT_SCOPE),
            *self.outputs("aggregate", scope=paths.REPLICATES_SCOPE),
            *self.outputs("notebook_scorecard", scope=paths.REPLICATES_SCOPE),
        ]
