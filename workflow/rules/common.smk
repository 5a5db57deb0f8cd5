# Shared helpers: config validation and the names of files the rules produce.

import os
import shlex
import sys

from snakemake.io import report as in_report  # `report(` opening a line is Snakemake's directive

from cape.bytecode import precompile_package
from cape.config import validate_config
from cape.controllers import controller_class
from cape.closedloop.disturbances import validate_sources
from cape.controllers.base import validate_settings
from cape.locks import clear_stale_locks
from cape.models.draws import choose_training, deciding_cap, default_max_trainings, read_outcome
from cape.models.registry import model_class
from cape.layout import paths
from cape.layout.names import TRUTH, PlantName, models_read, plant_names
from cape.layout.runs import RunId
from cape.study.grid import study_grid
from cape.study.outputs import STUDY_NOTEBOOKS, WHOLE_STUDY_NOTEBOOKS
from cape.study.question_plan import Plan, QuestionSettings, stage_runs
from cape.study.stale import missing_runs
from cape.tracks.manifest import BAYESRACE_FILES
from cape.workflow import specs


# Interrupted by SIGKILL, a run leaves its locks: the main Snakemake process removes them when
# it can prove that the run which wrote them has ended, so that the documented command resumes;
# anything it cannot prove is left alone, with a message (cape/locks.py).
if workflow.is_main_process:
    clear_stale_locks(".", report=lambda message: print(message, file=sys.stderr))
    # every job imports the package: its bytecode is written once here, so that no job
    # compiles the modules from source where PYTHONDONTWRITEBYTECODE is set (cape/bytecode.py)
    precompile_package()

SOURCE = "config (config/config.yaml and any --configfile)"
# the schema (shipped in the package: cape/schemas/config.schema.yaml, defaults filled in) and the cross-field
# rules, each problem one message naming the key and the fix
validate_config(config, SOURCE)
for _name, _entry in config["controllers"].items():  # each controller's own keys
    validate_settings(controller_class(_name, _entry), _name, _entry, SOURCE)
validate_sources(config["disturbances"], SOURCE)  # each disturbance source's own keys
for _name, _entry in config["models"].items():  # each model's module imports and registers it
    model_class(_name, _entry)

# The software environment of every rule for `--sdm conda` (relative to workflow/rules/).
CAPE_ENV = "../envs/cape.yaml"

TRACK_DIR = config["tracks"]["dir"]
DATA_TRACKS = sorted(config["data"]["tracks"])
MODELS = list(config["models"])
REPLICATES = int(config["training"]["replicates"])  # trained networks of every model (SPEC §4)


PLANT_NAMES = plant_names(MODELS)
ETAS = config["disturbances"]["eta"]

# Two scopes of the study's summaries: the default target's (`results/`: replicate 0, the
# single-draw study, ~1 h on two cores) and the `replicates` target's (`results/replicates/`:
# every training replicate of SPEC §4, about twice that), each with its runs.parquet, table 8,
# RESULTS.md and scorecard notebook.
SCOPES = {paths.DEFAULT_SCOPE: [0], paths.REPLICATES_SCOPE: list(range(REPLICATES))}


wildcard_constraints:
    track="|".join(sorted(config["tracks"]["catalogue"])),
    model="|".join(MODELS),
    study="|".join(sorted(config["study"]["studies"])),
    plant="|".join(PLANT_NAMES),
    internal="|".join(PLANT_NAMES),
    controller="|".join(sorted(config["controllers"])),
    eta=r"[0-9]+(\.[0-9]+)?",
    seed=r"[0-9]+",
    training_seed=r"[0-9]+",
    replicate=r"[0-9]+",
    scope="|".join(SCOPES),


def job_spec(job, text):
    """The path of a job's specification (cape.workflow.specs): its command reads the file."""
    return specs.spec_file(job, text)


def notebook_spec(name):
    """The specification of notebook ``name``: the config sections it declares it reads."""
    return job_spec(f"notebook_{name}", specs.sections(config, *NOTEBOOKS_DECLARED[name].reads))


def track_files():
    """The ten verified BayesRace files under the resources folder."""
    return [f"{TRACK_DIR}/{name}" for name in BAYESRACE_FILES]


def training_seed(k):
    """A model's k-th training has seed ``training.seed + k`` (SPEC §4)."""
    return int(config["training"]["seed"]) + int(k)


# A model's trainings, by seed; its draws are made from them (cape.models.draws)
TRAINING_FOLDER = paths.TRAINING
MODEL_FOLDER = paths.MODEL  # a model's draw
MAX_TRAININGS = int(config["training"].get("max_trainings") or default_max_trainings(REPLICATES))


def draw_choice(wildcards):
    """Which training draw r of a model is, asked for in the order of cape.models.draws (a
    training not yet checked is planned, and the draw waits for it)."""
    model = wildcards.model

    def outcome(k):
        path = checkpoints.training_health.get(model=model, training_seed=training_seed(k)).output[0]
        return read_outcome(path)

    return choose_training(int(wildcards.replicate), MAX_TRAININGS, outcome)


def draw_max_trainings(wildcards):
    """The cap a draw is made under (cape.models.draws.deciding_cap): more draws redo no old one."""
    return deciding_cap(draw_choice(wildcards), MAX_TRAININGS)


def draw_inputs(wildcards):
    """The trainings draw r of a model is chosen among: the chosen one's files and every
    consulted training's health record."""
    model = wildcards.model
    choice = draw_choice(wildcards)
    chosen = paths.training_dir(model, choice.consulted[choice.index].seed)
    return {
        "health": [f"{paths.training_dir(model, o.seed)}/{paths.HEALTH}" for o in choice.consulted],
        "weights": f"{chosen}/{paths.WEIGHTS}",
        "meta": f"{chosen}/{paths.META}",
        "losses": f"{chosen}/{paths.LOSSES}",
    }


def trained_models(replicate=0):
    """Weights, metadata and loss curve of every configured model's replicate."""
    return [
        f"{paths.model_dir(m, replicate)}/{f}" for m in MODELS for f in paths.MODEL_FILES
    ]


def model_args(replicate=0):
    """``--model NAME=DIR`` for every configured model's replicate."""
    return " ".join(f"--model {shlex.quote(f'{m}={paths.model_dir(m, replicate)}')}" for m in MODELS)


def training_data_arg(input):
    """``--training-data PATH`` for a run whose plant is bounded by the training data."""
    return f"--training-data {shlex.quote(input.training_data)}" if "training_data" in input.keys() else ""


def model_folder_args(wildcards, names):
    """``--model NAME=DIR`` for each trained model that the plants or internal models
    ``names`` read, of the rule's replicate: the command reads the models the rule declares."""
    replicate = int(wildcards.replicate)
    models = {m for name in names if (m := PlantName.parse(name).model) is not None}
    return " ".join(
        f"--model {shlex.quote(f'{m}={paths.model_dir(m, replicate)}')}" for m in sorted(models)
    )


def raceline_path():
    return paths.raceline(config["reference"]["track"])


def uses_internal_model(controller):
    """True for a controller that predicts with an internal model (the NMPCs)."""
    return controller_class(controller, config["controllers"][controller]).needs_internal_model


def model_inputs(role, name, replicate):
    """The files a plant or internal model ``name`` of training replicate ``replicate`` is read
    from: its exported network (a learned Φ) or its frozen Φ, and its meta.json; nothing for
    the ground truth."""
    plant = PlantName.parse(name)
    if plant.is_truth:
        return {}
    folder = paths.model_dir(plant.model, replicate)
    inputs = {f"{role}_meta": f"{folder}/{paths.META}"}
    if plant.kind == "learned":
        inputs[f"{role}_network"] = f"{folder}/{paths.NETWORK}"
    else:
        inputs[f"{role}_frozen"] = f"{folder}/{paths.FROZEN_PHI}"
    return inputs


def compiles_solver(controller):
    """True for a controller whose NLP is compiled to C (built once by the solver rule)."""
    settings = config["controllers"][controller].get("compile") or {}
    return uses_internal_model(controller) and bool(settings.get("enabled", False))


def solver_path(controller, internal, replicate):
    """A controller's solver for an internal model of one replicate (the true model's is
    replicate 0's for every replicate: no trained network enters it)."""
    return paths.solver(controller, internal, 0 if internal == TRUTH else replicate)


def rollout_models(wildcards):
    """The plant and, for a controller with one, the internal model a run reads."""
    if uses_internal_model(wildcards.controller):
        return [wildcards.plant, wildcards.internal]
    return [wildcards.plant]


def rollout_inputs(wildcards):
    """What one run reads: the reference line, the plant's and the internal model's files of
    the run's replicate, and the controller's compiled solver for that internal model."""
    replicate = int(wildcards.replicate)
    inputs = {"raceline": raceline_path(), **model_inputs("plant", wildcards.plant, replicate)}
    if wildcards.plant != TRUTH:  # its states bound a learned plant (SPEC §5.3)
        inputs["training_data"] = paths.dataset(config["data"]["train_track"])
    if uses_internal_model(wildcards.controller):
        inputs.update(model_inputs("internal", wildcards.internal, replicate))
    if compiles_solver(wildcards.controller):
        inputs["solver"] = solver_path(wildcards.controller, wildcards.internal, replicate)
    return inputs


def solver_inputs(wildcards):
    """What building a controller's NLP reads: the reference line and the internal model."""
    internal = model_inputs("internal", wildcards.internal, int(wildcards.replicate))
    return {"raceline": raceline_path(), **internal}


# Every run of the grid, each with the run that computes it (a run asked for by two studies,
# the ablation's diagonal, is computed once): cape.study.grid, which `cape aggregate` also calls
GRID = study_grid(config, SOURCE)
RUN_FOLDER = str(RunId.wildcards().folder())  # a run's files, its log and its figure, as
RUN_LOG = str(RunId.wildcards().folder(paths.log("runs")))  # the rules' wildcard patterns
RUN_STEM = RunId.wildcards().stem()


def rollout_targets(replicates=None):
    """metrics.json of every run the grid computes (each once); ``replicates``: only the runs
    of these training replicates (the default target's are replicate 0's)."""
    return [f"{run.folder()}/{paths.METRICS}" for run in computed_runs(replicates)]


# --- the study's notebooks -------------------------------------------------------------------
NOTEBOOKS = os.path.join(workflow.basedir, "notebooks")  # beside the Snakefile, whatever -d is
TABLE_EXTS = [".csv", ".md", ".tex"]
STUDIES = config["study"]["studies"]
NOTEBOOKS_DECLARED = {**STUDY_NOTEBOOKS, **WHOLE_STUDY_NOTEBOOKS}


def studies_of_kind(kind):
    """A wildcard constraint: the studies of ``kind`` (a pattern that matches nothing if none)."""
    names = [s for s, grid in STUDIES.items() if grid.get("kind", "closed_loop") == kind]
    return "|".join(names) or "(?!)"


def figures(notebook, folder, ext):
    """The figures a notebook declares (cape.study.outputs), as files in ``folder``."""
    declared = NOTEBOOKS_DECLARED[notebook]
    return [f"{folder}/{name}{ext}" for name in declared.figures]


def reported_figures(notebook, folder, caption, category):
    """The PNG copies of a notebook's figures for the report, each labelled with its number and
    its title (cape.study.outputs): a category then lists its figures in order, by what they
    show, rather than by file name under one shared caption."""
    declared = NOTEBOOKS_DECLARED[notebook]
    return [
        in_report(
            f"{folder}/{name}.png",
            caption=caption,
            category=category,
            labels={"figure": name[:5], "title": title},
        )
        for name, title in declared.figures.items()
    ]


def tables(notebook, folder):
    """The tables a notebook declares, as .csv, .md and .tex files in ``folder``."""
    declared = NOTEBOOKS_DECLARED[notebook]
    return [f"{folder}/{name}{ext}" for name in declared.tables for ext in TABLE_EXTS]


def run_notebook(arguments):
    """The shell command of a notebook rule: papermill runs it under a `.part.ipynb` name (it
    writes as it runs), nbconvert makes the HTML copy, and the notebook is renamed last, so an
    interrupted notebook never looks finished. A notebook that fails leaves nothing beside the
    results: its executed copy, which shows the failing cell, goes beside its log (the log says
    so only when there is one). Every path is quoted: a checkout may have spaces in its path."""
    return (
        "(papermill {input.notebook:q} {output.notebook:q}.part.ipynb --cwd . --no-progress-bar "
        + arguments
        + " > {log:q} 2>&1"
        " && jupyter nbconvert --to html {output.notebook:q}.part.ipynb --output-dir \"$(dirname {output.html:q})\""
        " --output \"$(basename {output.html:q} .html)\""
        " --HTMLExporter.preprocessors=cape.study.notebook_html.ShortParameters >> {log:q} 2>&1"
        " && mv {output.notebook:q}.part.ipynb {output.notebook:q})"
        " || ((mv -f {output.notebook:q}.part.ipynb {log:q}.failed.ipynb 2> /dev/null"
        " && echo \"the notebook failed; its executed copy, with the failing cell: \"{log:q}.failed.ipynb"
        " || echo 'the notebook failed before it ran (no executed copy); the messages above say why')"
        " >> {log:q}; exit 1)"
    )


def example_series(study):
    """The time series the η = 0 figures draw: every run of ``study`` at η = 0, first seed,
    replicate 0 (the study's figures are replicate 0's)."""
    return [
        f"{computed.folder()}/{paths.SERIES}"
        for run, computed in GRID.items()
        if run.study == study and float(run.eta) == 0 and run.seed == 0 and run.replicate == 0
    ]


def scorecard_inputs(wildcards):
    """What the scorecard of a scope reads beyond its runs: tables 1 and 4 and the trained
    models' meta.json and loss.csv of each of the scope's replicates."""
    replicates = SCOPES[wildcards.scope]
    return {
        "complexity": [paths.replicate_table(r, "table01_model_complexity") for r in replicates],
        "openloop": [paths.replicate_table(r, "table04_openloop_rmse") for r in replicates],
        "models": [path for r in replicates for path in trained_models(r) if not path.endswith(".pt")],
    }


def papermill_args(job, **parameters):
    """``-f FILE``: a notebook's parameters, written as job ``job``'s specification."""
    return f"-f {shlex.quote(job_spec(job, specs.notebook_parameters(parameters)))}"


def job_outputs(name, **wildcards):
    """Every file that one job of ``name`` writes: its output patterns with ``wildcards`` filled.

    A target lists every file of every job it comprises, not only the last ones: Snakemake does
    not rebuild a deleted file that no target asks for (nor the rest of a job's outputs), so a
    deleted model, run, table or figure is rebuilt, with everything downstream, only if the
    target names it."""
    return [str(pattern).format(**wildcards) for pattern in getattr(rules, name).output]


def run_outputs(runs):
    """The files of every run in ``runs`` (RunIds), each once."""
    return [
        path
        for run in dict.fromkeys(runs)
        for path in job_outputs("rollout", study=run.study, replicate=run.replicate, plant=run.plant,
                                internal=run.internal, controller=run.controller, eta=run.eta,
                                seed=run.seed)  # fmt: skip
    ]


def model_outputs(replicates):
    """Every file of the model stage for these training replicates: each model's training,
    exported network and frozen Φ, tables 1 and 4."""
    files = []
    for r in replicates:
        for m in MODELS:
            for stage in ("draw", "freeze", "export_network"):
                files += job_outputs(stage, model=m, replicate=r)
        files += job_outputs("openloop_table", replicate=r) + job_outputs("complexity_table", replicate=r)
    return files


def solver_outputs(runs):
    """The compiled solver of every run in ``runs`` that uses one."""
    return list(
        dict.fromkeys(
            solver_path(run.controller, run.internal, run.replicate)
            for run in runs
            if compiles_solver(run.controller)
        )
    )


def computed_runs(replicates=None):
    """The runs the grid computes (each once), of these training replicates (all: None)."""
    return list(
        dict.fromkeys(
            computed for run, computed in GRID.items() if replicates is None or run.replicate in replicates
        )
    )


def study_targets():
    """Every table, figure and executed notebook of the default target's study, and the
    aggregation they read: per study, the notebook of its kind and the failure map; the set-up
    notebook; the scorecard when the paper's study is in the grid (its claims are about it)."""
    scope = paths.DEFAULT_SCOPE
    targets = job_outputs("aggregate", scope=scope) + job_outputs("notebook_setup")
    for study, grid in STUDIES.items():
        kind = grid.get("kind", "closed_loop")
        targets += job_outputs(f"notebook_{kind}", study=study)
        targets += job_outputs("notebook_failures", study=study)
    if config["study"].get("paper") in STUDIES:
        targets += job_outputs("notebook_scorecard", scope=scope)
    return targets


def replicate_targets():
    """The `replicates` target: every replicate's models and the paper's study for each, with
    its scorecard (verdicts per replicate and pooled) under results/replicates/, and every file
    those are made from (the default target's runs among them: the scorecard reads its
    summary)."""
    if config["study"].get("paper") not in STUDIES:
        return []
    runs = computed_runs()
    return [
        *model_outputs(range(REPLICATES)),
        *solver_outputs(runs),
        *run_outputs(runs),
        *job_outputs("aggregate", scope=paths.DEFAULT_SCOPE),
        *job_outputs("aggregate", scope=paths.REPLICATES_SCOPE),
        *job_outputs("notebook_scorecard", scope=paths.REPLICATES_SCOPE),
    ]


def all_targets():
    """The default target: every file the workflow makes for training replicate 0."""
    runs = computed_runs({0})
    return [
        *job_outputs("tracks"),
        *(path for t in DATA_TRACKS for path in job_outputs("dataset", track=t)),
        *job_outputs("figure_tracks"),
        *model_outputs([0]),
        *job_outputs("figure_models"),
        *job_outputs("raceline", track=config["reference"]["track"]),
        *solver_outputs(runs),
        *run_outputs(runs),
        *study_targets(),
    ]


def question_targets():
    """Every file of the runs the current stage's plan names, with their compiled solvers."""
    plan = (config.get("question") or {}).get("plan")
    if not plan:
        return []
    settings = QuestionSettings.from_config(config, SOURCE)
    runs = [GRID.get(run, run) for run in stage_runs(settings, Plan.from_config(plan))]
    return [*solver_outputs(runs), *run_outputs(runs)]
