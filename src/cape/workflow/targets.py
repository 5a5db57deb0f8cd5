"""The study's workflow logic, for the rules to call: the grid and its targets, the draws, the
files each job reads and the arguments it gets.

``StudyWorkflow`` is built once from the validated config and two functions of Snakemake's:
``outputs(rule, **wildcards)``, the files one job of a rule writes, and ``health(model,
seed)``, a training's health record through the checkpoint (its outcome decides the draws).
"""

from __future__ import annotations

import hashlib
import os
import shlex
import sys
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager, suppress
from dataclasses import asdict, dataclass
from typing import Any

from cape.bytecode import precompile_package
from cape.controllers import controller_class
from cape.errors import CapeError, one_line
from cape.layout import paths
from cape.layout.names import TRUTH, PlantName, plant_names
from cape.layout.runs import RunId
from cape.models.draws import (
    Choice,
    Outcome,
    choose_training,
    deciding_cap,
    default_max_trainings,
    read_outcome,
)
from cape.specs.study import StudyGrid, StudySpec
from cape.storage.locks import clear_stale_locks
from cape.study.grid import study_grid
from cape.study.outputs import STUDY_NOTEBOOKS, WHOLE_STUDY_NOTEBOOKS, NotebookOutputs
from cape.study.question_plan import Plan, QuestionSettings, stage_runs
from cape.study.stale import missing_runs
from cape.tracks.manifest import BAYESRACE_FILES
from cape.workflow import job_files
from cape.workflow.scheduler import bound_wakeup_timers

SOURCE = "config (config/config.yaml and any --configfile)"
TABLE_EXTS = (".csv", ".md", ".tex")
NOTEBOOKS: dict[str, NotebookOutputs] = {**STUDY_NOTEBOOKS, **WHOLE_STUDY_NOTEBOOKS}
RUN_FOLDER = str(RunId.wildcards().folder())
"""A run's folder, its log and its figure's stem, as the rules' wildcard patterns."""
RUN_LOG = str(RunId.wildcards().folder(paths.log("runs")))
RUN_STEM = RunId.wildcards().stem()
COMPLEXITY_TABLE, OPENLOOP_TABLE = "table01_model_complexity", "table04_openloop_rmse"

Outputs = Callable[..., list[str]]
Health = Callable[[str, int], str]


def prepare(config: Mapping[str, Any], main_process: bool) -> None:
    """Before any rule: in the main process, remove the locks of runs proven ended
    (cape/storage/locks.py) and write the package's bytecode once (cape/bytecode.py); everywhere,
    validate the config (cape.workflow.job_files.validate) and bound the scheduler's wake-up timers
    (cape/workflow/scheduler.py)."""
    bound_wakeup_timers()
    if main_process:
        clear_stale_locks(".", report=lambda message: print(message, file=sys.stderr))
        precompile_package()
    job_files.validate(config, SOURCE)


@contextmanager
def refusals() -> Iterator[None]:
    """A ``CapeError`` raised while Snakemake reads the workflow (a bad config value, a grid it
    cannot build) as its one-line reason on stderr and exit status 1. Snakemake would print
    any exception, ``WorkflowError`` included, with the ``File "…"`` lines of its traceback,
    which tell a user who gave a bad value nothing; a ``SystemExit`` it lets through."""
    try:
        yield
    except CapeError as error:
        print(f"error: {one_line(str(error))}", file=sys.stderr)  # as `cape` says it
        raise SystemExit(1) from None


class _MissingRecordError(Exception):
    """A health record a draw asks for is neither made nor being read (``draw_inputs``)."""


@dataclass(frozen=True)
class StudyWorkflow:
    """The grid of a validated config and everything the rules compute from it
    (``from_config``)."""

    config: Mapping[str, Any]
    """The validated config, for the question's settings alone."""
    study: StudySpec
    grid: Mapping[RunId, RunId]
    outputs: Outputs
    health: Health
    models: tuple[str, ...]
    max_trainings: int
    training_seed0: int
    tracks: tuple[str, ...]
    tracks_dir: str
    data_tracks: tuple[str, ...]
    train_track: str
    test_track: str
    reference_track: str
    time_limit: float
    threads: int
    """Threads per training."""
    checkpoint_every: float
    """Seconds between a training's resumable checkpoints."""
    plan: Mapping[str, Any] | None
    """The question's current stage (``question.plan``, written by `cape question`)."""

    @classmethod
    def from_config(
        cls, config: Mapping[str, Any], outputs: Outputs, health: Health
    ) -> StudyWorkflow:
        study = StudySpec.from_config(config)
        training = config["training"]
        cap = training.get("max_trainings")
        return cls(
            config=config,
            study=study,
            grid=study_grid(study, SOURCE),
            outputs=outputs,
            health=health,
            models=tuple(config["models"]),
            max_trainings=int(cap or default_max_trainings(study.replicates)),
            training_seed0=int(training["seed"]),
            tracks=tuple(sorted(config["tracks"]["catalogue"])),
            tracks_dir=str(config["tracks"]["dir"]),
            data_tracks=tuple(sorted(config["data"]["tracks"])),
            train_track=str(config["data"]["train_track"]),
            test_track=str(config["data"]["test_track"]),
            reference_track=str(config["reference"]["track"]),
            time_limit=config["rollout"]["time_limit"],
            threads=int(training["threads"]),
            checkpoint_every=training.get("checkpoint_every", 60),
            plan=(config.get("question") or {}).get("plan"),
        )

    @property
    def replicates(self) -> int:
        """Trained networks (draws) of every model (SPEC §4)."""
        return self.study.replicates

    @property
    def scopes(self) -> dict[str, list[int]]:
        """The study's two summaries: the default target's (replicate 0) and the `replicates`
        target's (every draw), each with its runs.parquet, table 8, RESULTS.md and scorecard."""
        return {paths.DEFAULT_SCOPE: [0], paths.REPLICATES_SCOPE: list(range(self.replicates))}

    @property
    def studies(self) -> Mapping[str, StudyGrid]:
        return self.study.studies

    def constraints(self) -> dict[str, str]:
        """The wildcards' patterns."""
        names = plant_names(self.models)
        return {
            "track": "|".join(self.tracks),
            "model": "|".join(self.models),
            "study": "|".join(sorted(self.studies)),
            "plant": "|".join(names),
            "internal": "|".join(names),
            "controller": "|".join(sorted(self.study.controllers)),
            "eta": r"[0-9]+(\.[0-9]+)?",
            "seed": r"[0-9]+",
            "training_seed": r"[0-9]+",
            "replicate": r"[0-9]+",
            "scope": "|".join(self.scopes),
        }

    def studies_of_kind(self, kind: str) -> str:
        """A wildcard constraint: the studies of ``kind`` (a pattern matching none if none)."""
        names = [s for s, grid in self.studies.items() if grid.kind == kind]
        return "|".join(names) or "(?!)"

    # --- the model stage ---------------------------------------------------------------------
    def track_files(self) -> list[str]:
        """The verified BayesRace files under the resources folder."""
        return [f"{self.tracks_dir}/{name}" for name in BAYESRACE_FILES]

    def training_seed(self, k: int) -> int:
        """A model's k-th training has seed ``training.seed + k`` (SPEC §4)."""
        return self.training_seed0 + int(k)

    def training_priority(self, model: str) -> int:
        """The longest training first (EPM's 3000 epochs are the study's critical path), and
        every training before any rollout."""
        return 100 + int(self.study.models[model]["train"]["epochs"]) // 10

    def draw_choice(self, wildcards: Any) -> Choice:
        """Which training draw r of a model is, asked for in the order of cape.models.draws
        (a training not yet checked is planned, and the draw waits for it)."""
        model = wildcards.model

        def outcome(k: int) -> Any:
            return read_outcome(self.health(model, self.training_seed(k)))

        return choose_training(int(wildcards.replicate), self.max_trainings, outcome)

    def _choice_or_none(self, wildcards: Any) -> Choice | None:
        """``draw_choice``, or None when a record it reads is no health record: the draw job
        then runs and `cape draw` says what is wrong in one line (its log), not the planner
        in a traceback."""
        try:
            return self.draw_choice(wildcards)
        except CapeError:
            return None

    def draw_max_trainings(self, wildcards: Any) -> int:
        """The cap a draw is made under (cape.models.draws.deciding_cap)."""
        choice = self._choice_or_none(wildcards)
        return self.max_trainings if choice is None else deciding_cap(choice, self.max_trainings)

    @staticmethod
    def draw_records(health: Iterable[str]) -> str:
        """The content of the health records a draw reads (its ``health`` inputs that exist),
        as a digest: a param of the draw rule, so a record changed in place re-decides the
        draw, whatever its file's time."""
        digest = hashlib.sha256()
        for path in health:
            if os.path.exists(path):
                with open(path, "rb") as record:
                    digest.update(hashlib.sha256(record.read()).digest())
        return digest.hexdigest()[:16]

    def draw_inputs(self, wildcards: Any) -> dict[str, Any]:
        """The trainings draw r of a model is chosen among: every consulted training's health
        record, weights, metadata and loss curve (`cape draw` checks each record against them),
        in seed order.

        A record the draw needs that is still to be made is Snakemake's checkpoint target
        while its file exists (Snakemake reads it when it updates the checkpoint's dependents),
        but a plain input once the file is missing: a job with a checkpoint target among its
        inputs is exempt from every rerun trigger of its own (its outputs' age, params, input
        set), so a draw whose record changed such that it now needs a training not yet made
        was left as it was ("Nothing to be done"); as a plain input the draw is rerun, and it is
        planned again when the record is made (Snakemake updates a checkpoint's dependents when
        it finishes)."""
        from snakemake.exceptions import IncompleteCheckpointException

        model = wildcards.model
        read: dict[int, str] = {}  # training index → its record, as the draw asked for them
        missing: list[str] = []

        def outcome(k: int) -> Outcome:
            try:
                record = self.health(model, self.training_seed(k))
            except IncompleteCheckpointException as pending:
                if os.path.exists(pending.targetfile):
                    raise
                missing.append(str(pending.targetfile))
                raise _MissingRecordError from None
            read[k] = record
            try:
                return read_outcome(record)
            except CapeError:  # `cape draw` refuses it in one line: the job runs to say so
                raise _MissingRecordError from None

        with suppress(_MissingRecordError):  # planned again once that record is made
            choose_training(int(wildcards.replicate), self.max_trainings, outcome)
        folders = [os.path.dirname(read[k]) for k in sorted(read)]  # seed order
        return {
            "health": [read[k] for k in sorted(read)] + missing,
            "weights": [f"{f}/{paths.WEIGHTS}" for f in folders],
            "meta": [f"{f}/{paths.META}" for f in folders],
            "losses": [f"{f}/{paths.LOSSES}" for f in folders],
        }

    def trained_models(self, replicate: int = 0) -> list[str]:
        """Weights, metadata and loss curve of every configured model's draw ``replicate``."""
        return [
            f"{paths.model_dir(m, replicate)}/{f}" for m in self.models for f in paths.MODEL_FILES
        ]

    def model_args(self, replicate: int = 0) -> str:
        """``--model NAME=DIR`` for every configured model's draw."""
        return self._model_args(self.models, replicate)

    # --- the closed loop ---------------------------------------------------------------------
    @staticmethod
    def _model_args(models: Iterable[str], replicate: int) -> str:
        return " ".join(
            f"--model {shlex.quote(f'{m}={paths.model_dir(m, replicate)}')}" for m in models
        )

    def model_folder_args(self, wildcards: Any, names: Iterable[str]) -> str:
        """``--model NAME=DIR`` for each trained model the plants or internal models
        ``names`` read, of the rule's draw."""
        models = {m for name in names if (m := PlantName.parse(name).model) is not None}
        return self._model_args(sorted(models), int(wildcards.replicate))

    @staticmethod
    def training_data_arg(inputs: Any) -> str:
        """``--training-data PATH`` for a run whose plant is bounded by the training data."""
        if "training_data" not in inputs.keys():  # noqa: SIM118 (a Namedlist: `in` sees values)
            return ""
        return f"--training-data {shlex.quote(inputs.training_data)}"

    def raceline_path(self) -> str:
        return paths.raceline(self.reference_track)

    def uses_internal_model(self, controller: str) -> bool:
        """True for a controller that predicts with an internal model (the NMPCs)."""
        entry = self.study.controllers[controller]
        return bool(controller_class(controller, entry).needs_internal_model)

    def compiles_solver(self, controller: str) -> bool:
        """True for a controller whose NLP is compiled to C (built once by the solver rule)."""
        settings = self.study.controllers[controller].get("compile") or {}
        return self.uses_internal_model(controller) and bool(settings.get("enabled", False))

    @staticmethod
    def solver_path(controller: str, internal: str, replicate: int) -> str:
        """A controller's solver for an internal model of one draw (the true model's is draw
        0's for every draw: no trained network enters it)."""
        return paths.solver(controller, internal, 0 if internal == TRUTH else replicate)

    @staticmethod
    def model_inputs(role: str, name: str, replicate: int) -> dict[str, str]:
        """The files a plant or internal model ``name`` of draw ``replicate`` is read from: its
        exported network (a learned Φ) or frozen Φ, and its metadata; none for the truth."""
        plant = PlantName.parse(name)
        if plant.is_truth or plant.model is None:
            return {}
        folder = paths.model_dir(plant.model, replicate)
        inputs = {f"{role}_meta": f"{folder}/{paths.META}"}
        if plant.kind == "learned":
            inputs[f"{role}_network"] = f"{folder}/{paths.NETWORK}"
        else:
            inputs[f"{role}_frozen"] = f"{folder}/{paths.FROZEN_PHI}"
        return inputs

    def rollout_models(self, wildcards: Any) -> list[str]:
        """The plant and, for a controller with one, the internal model a run reads."""
        if self.uses_internal_model(wildcards.controller):
            return [wildcards.plant, wildcards.internal]
        return [wildcards.plant]

    def rollout_inputs(self, wildcards: Any) -> dict[str, str]:
        """What one run reads: the reference line, the plant's and internal model's files of
        the run's draw, and the controller's compiled solver for that internal model."""
        replicate = int(wildcards.replicate)
        inputs = {
            "raceline": self.raceline_path(),
            **self.model_inputs("plant", wildcards.plant, replicate),
        }
        if wildcards.plant != TRUTH:  # its states bound a learned plant (SPEC §5.3)
            inputs["training_data"] = paths.dataset(self.train_track)
        if self.uses_internal_model(wildcards.controller):
            inputs.update(self.model_inputs("internal", wildcards.internal, replicate))
        if self.compiles_solver(wildcards.controller):
            inputs["solver"] = self.solver_path(wildcards.controller, wildcards.internal, replicate)
        return inputs

    def solver_inputs(self, wildcards: Any) -> dict[str, str]:
        """What building a controller's NLP reads: the reference line and the internal model."""
        internal = self.model_inputs("internal", wildcards.internal, int(wildcards.replicate))
        return {"raceline": self.raceline_path(), **internal}

    # --- the study's notebooks ---------------------------------------------------------------
    @staticmethod
    def figures(notebook: str, folder: str, ext: str) -> list[str]:
        """The figures a notebook declares (cape.study.outputs), as files in ``folder``."""
        return [f"{folder}/{name}{ext}" for name in NOTEBOOKS[notebook].figures]

    @staticmethod
    def tables(notebook: str, folder: str) -> list[str]:
        """The tables a notebook declares, as .csv, .md and .tex files in ``folder``."""
        return [
            f"{folder}/{name}{ext}" for name in NOTEBOOKS[notebook].tables for ext in TABLE_EXTS
        ]

    def example_series(self, study: str) -> list[str]:
        """The time series the η = 0 figures draw: every run of ``study`` at η = 0, first
        seed, draw 0 (the study's figures are draw 0's)."""
        return [
            f"{computed.folder()}/{paths.SERIES}"
            for run, computed in self.grid.items()
            if run.study == study and float(run.eta) == 0 and run.seed == 0 and run.replicate == 0
        ]

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
                for path in self.trained_models(r)
                if not path.endswith(paths.WEIGHTS)
            ],
        }

    # --- targets -----------------------------------------------------------------------------
    def computed_runs(self, replicates: Iterable[int] | None = None) -> list[RunId]:
        """The runs the grid computes (each once), of these draws (all: None)."""
        wanted = None if replicates is None else set(replicates)
        return list(
            dict.fromkeys(
                computed
                for run, computed in self.grid.items()
                if wanted is None or run.replicate in wanted
            )
        )

    def rollout_targets(self, replicates: Iterable[int] | None = None) -> list[str]:
        """metrics.json of every run the grid computes (each once), of these draws."""
        return [f"{run.folder()}/{paths.METRICS}" for run in self.computed_runs(replicates)]

    def run_outputs(self, runs: Iterable[RunId]) -> list[str]:
        """The files of every run in ``runs``, each once."""
        return [
            path for run in dict.fromkeys(runs) for path in self.outputs("rollout", **asdict(run))
        ]

    def model_outputs(self, replicates: Iterable[int]) -> list[str]:
        """Every file of the model stage for these draws: each model's draw, exported network
        and frozen Φ, tables 1 and 4."""
        files: list[str] = []
        for r in replicates:
            for m in self.models:
                for stage in ("draw", "freeze", "export_network"):
                    files += self.outputs(stage, model=m, replicate=r)
            files += self.outputs("openloop_table", replicate=r)
            files += self.outputs("complexity_table", replicate=r)
        return files

    def solver_outputs(self, runs: Iterable[RunId]) -> list[str]:
        """The compiled solver of every run in ``runs`` that uses one."""
        return list(
            dict.fromkeys(
                self.solver_path(run.controller, run.internal, run.replicate)
                for run in runs
                if self.compiles_solver(run.controller)
            )
        )

    def study_targets(self) -> list[str]:
        """Every table, figure and executed notebook of the default target's study and the
        aggregation they read: per study, the notebook of its kind and the failure map; the
        set-up notebook; the scorecard when the paper's study is in the grid."""
        scope = paths.DEFAULT_SCOPE
        targets = self.outputs("aggregate", scope=scope) + self.outputs("notebook_setup")
        for study, grid in self.studies.items():
            targets += self.outputs(f"notebook_{grid.kind}", study=study)
            targets += self.outputs("notebook_failures", study=study)
        if self.study.paper in self.studies:
            targets += self.outputs("notebook_scorecard", scope=scope)
        return targets

    def replicate_targets(self) -> list[str]:
        """The `replicates` target: every draw's models and the paper's study for each, with
        its scorecard under results/replicates/, and every file those are made from."""
        if self.study.paper not in self.studies:
            return []
        runs = self.computed_runs()
        return [
            *self.model_outputs(range(self.replicates)),
            *self.solver_outputs(runs),
            *self.run_outputs(runs),
            *self.outputs("aggregate", scope=paths.DEFAULT_SCOPE),
            *self.outputs("aggregate", scope=paths.REPLICATES_SCOPE),
            *self.outputs("notebook_scorecard", scope=paths.REPLICATES_SCOPE),
        ]

    def all_targets(self) -> list[str]:
        """The default target: every file the workflow makes for draw 0."""
        runs = self.computed_runs({0})
        return [
            *self.outputs("tracks"),
            *(path for t in self.data_tracks for path in self.outputs("dataset", track=t)),
            *self.outputs("figure_tracks"),
            *self.model_outputs([0]),
            *self.outputs("figure_models"),
            *self.outputs("raceline", track=self.reference_track),
            *self.solver_outputs(runs),
            *self.run_outputs(runs),
            *self.study_targets(),
        ]

    def question_targets(self) -> list[str]:
        """Every file of the runs the question's current stage names, with their solvers."""
        if not self.plan:
            return []
        settings = QuestionSettings.from_config(self.config, SOURCE)
        runs = [
            self.grid.get(run, run) for run in stage_runs(settings, Plan.from_config(self.plan))
        ]
        return [*self.solver_outputs(runs), *self.run_outputs(runs)]

    def stale_summaries(self) -> list[str]:
        """A message for each scope's runs.parquet whose runs are not all there: the targets
        that name every file rebuild them and it; asked for alone it would stay as it is."""
        messages = []
        for scope, replicates in self.scopes.items():
            metrics = (f"{run.folder()}/{paths.METRICS}" for run in self.computed_runs(replicates))
            missing = missing_runs(paths.study_runs(scope), metrics)
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
        " --HTMLExporter.preprocessors=cape.study.notebook_html.ShortParameters >> {log:q} 2>&1"
        " && mv {output.notebook:q}.part.ipynb {output.notebook:q})"
        " || ((mv -f {output.notebook:q}.part.ipynb {log:q}.failed.ipynb 2> /dev/null"
        ' && echo "the notebook failed; its executed copy, with the failing cell: "'
        "{log:q}.failed.ipynb"
        " || echo 'the notebook failed before it ran (no executed copy); the messages above say"
        " why') >> {log:q}; exit 1)"
    )
