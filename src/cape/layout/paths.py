"""Where CAPE's files live: every folder and file name the workflow, the ``cape`` commands and
the notebooks share, spelled here once.

Each location is a template whose ``{fields}`` are the workflow's wildcards of the same name
(``str.format`` fills them; Snakemake reads them as wildcards), and a function fills it for a
caller that knows the values. Everything is relative to the working directory, the
checkout's root when run by Snakemake.
"""

from __future__ import annotations

from pathlib import Path

from cape.layout.names import replicate_name

RESULTS = "results"
REP = replicate_name("{replicate}")
"""A training replicate (draw) as a folder name, a wildcard pattern."""


def _under(*parts: str) -> str:
    return "/".join((RESULTS, *parts))


# --- inputs and the model stage ------------------------------------------------------------
DATASET = _under("data", "DYN-PP-{track}.npz")
RACELINE = _under("raceline", "{track}.npz")
TRAINING = _under("trainings", "{model}", "seed{training_seed}")
"""One training of a model (its k-th: seed training.seed + k): model.pt, meta.json, loss.csv,
health.json."""
MODELS = _under("models")
MODEL = _under("models", REP, "{model}")
"""A model's draw r: the training chosen for it, its frozen Φ and exported network."""
# --- the file names inside a folder, spelled only here ---------------------------------------
WEIGHTS = "model.pt"
META = "meta.json"
LOSSES = "loss.csv"
HEALTH = "health.json"
FROZEN_PHI = "frozen_phi.json"
NETWORK = "network.npz"
METRICS = "metrics.json"
TIMING = "timing.json"
SERIES = "timeseries.parquet"
RUNS_TABLE = "runs.parquet"
SUMMARY_TABLE = "summary.parquet"

MODEL_FILES = (WEIGHTS, META, LOSSES)
"""What a training writes into its folder, and a draw copies into its own."""
BESIDE_A_MODEL = (HEALTH, FROZEN_PHI, NETWORK)
"""What other rules write into a model's folder: its health, frozen Φ and exported network."""
CHECKPOINT_GLOB = "checkpoint-*.pt"
"""A training's resumable checkpoints, in its folder while it runs."""
SPECS = _under("specs")
SPEC = _under("specs", "{job}", "{digest}.json")
"""A job's specification: the config sections it reads, as JSON named by their digest."""
SOLVERS = _under("solvers")
SOLVER = _under("solvers", REP, "{controller}", "{internal}.json")
REPLICATE_TABLES = _under("tables", REP)
"""Tables of one draw's models (tables 1 and 4)."""

# --- the closed loop and the study -------------------------------------------------------
RUNS = _under("runs")
FIGURES = _under("figures")
TABLES = _under("tables")
NOTEBOOKS = _under("notebooks")
LOGS = _under("logs")
BENCHMARKS = _under("benchmarks")
ROLLOUT_FIGURES = _under("figures", "rollout")

DEFAULT_SCOPE = RESULTS
"""The default target's summaries (replicate 0)."""
REPLICATES_SCOPE = _under("replicates")
"""The ``replicates`` target's summaries (every draw)."""
STUDY_RUNS = f"{{scope}}/study/{RUNS_TABLE}"
STUDY_SUMMARY = f"{{scope}}/study/{SUMMARY_TABLE}"
GLANCE = "{scope}/RESULTS.md"
EVIDENCE = "{scope}/evidence"
"""A scope's tables 8 and 9 re-derive from this folder alone (cape.study.reports.scorecard_data)."""
EVIDENCE_FILES = ("values.csv", "draw_tables.csv", "draws.json", "evidence.json")
"""Its files: every run's values the tables read, tables 1 and 4 per draw, each draw's training
record (meta.json), and the settings and measured numbers the tables read."""
STUDY_PROVENANCE = "provenance.json"
"""A published study's provenance (`cape replicates --publish`), beside its copies."""
QUESTION = _under("question")
"""The ground-truth question in stages (`cape question`): its stage plan, looks and report."""
QUESTION_STAGE = f"{QUESTION}/stage.yaml"
QUESTION_LOOKS = f"{QUESTION}/looks.csv"
QUESTION_STATE = f"{QUESTION}/looks.json"
QUESTION_REPORT = f"{QUESTION}/RESULTS.md"
QUESTION_COMPONENTS = f"{QUESTION}/variance_components.csv"
QUESTION_VALUES = f"{QUESTION}/values.csv"
"""Each row's metric per (model, draw, seed): the data every look is decided from."""
QUESTION_PROVENANCE = "provenance.json"
"""A published question's provenance, beside its copies of the files above."""


def dataset(track: str) -> str:
    return DATASET.format(track=track)


def raceline(track: str) -> str:
    return RACELINE.format(track=track)


def training_dir(model: str, training_seed: int) -> str:
    return TRAINING.format(model=model, training_seed=int(training_seed))


def model_dir(model: str, replicate: int = 0) -> str:
    return MODEL.format(model=model, replicate=int(replicate))


def model_under(root: str | Path, model: str, replicate: int) -> Path:
    """A model's draw ``replicate`` under a models folder ``root`` (``MODELS`` or a copy)."""
    return Path(root, replicate_name(replicate), model)


def models_of(replicate: int = 0) -> str:
    """The folder of one draw's models (``results/models/rep<r>``)."""
    return f"{MODELS}/{replicate_name(replicate)}"


def solver(controller: str, internal: str, replicate: int) -> str:
    return SOLVER.format(controller=controller, internal=internal, replicate=int(replicate))


def replicate_table(replicate: int, name: str) -> str:
    """Table ``name`` (a .csv) of draw ``replicate``'s models."""
    return f"{REPLICATE_TABLES.format(replicate=int(replicate))}/{name}.csv"


def study_runs(scope: str = DEFAULT_SCOPE) -> str:
    return STUDY_RUNS.format(scope=scope)


def study_summary(scope: str = DEFAULT_SCOPE) -> str:
    return STUDY_SUMMARY.format(scope=scope)


def glance(scope: str = DEFAULT_SCOPE) -> str:
    return GLANCE.format(scope=scope)


def evidence(scope: str = DEFAULT_SCOPE, name: str = "") -> str:
    """A scope's evidence folder, or its file ``name`` (one of ``EVIDENCE_FILES``)."""
    folder = EVIDENCE.format(scope=scope)
    return f"{folder}/{name}" if name else folder


def scoped(scope: str, kind: str, *parts: str) -> str:
    """``<scope>/<kind>/<parts>``: a scope's tables, figures, notebooks, logs or benchmarks."""
    return "/".join((scope, kind, *parts))


def figures(*parts: str) -> str:
    return "/".join((FIGURES, *parts))


def tables(*parts: str) -> str:
    return "/".join((TABLES, *parts))


def notebooks(*parts: str) -> str:
    return "/".join((NOTEBOOKS, *parts))


def log(*parts: str) -> str:
    return "/".join((LOGS, *parts))


def benchmark(*parts: str) -> str:
    return "/".join((BENCHMARKS, *parts))
