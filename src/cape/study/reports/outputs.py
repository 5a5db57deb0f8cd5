"""Every table and figure of the study, declared once: which notebook writes it, and for which
kind of study (SPEC §9).

The workflow's rules read these lists for their outputs; the notebooks' ``save`` and
``save_table`` refuse a name that is not declared here. So a new figure is one entry below (its
name and title) plus the notebook cell that draws it, under that title. The kinds of study:
docs/modules.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

KINDS = ("closed_loop", "bicycle", "ablation")


@dataclass(frozen=True)
class NotebookOutputs:
    """What one notebook writes: figure stems (``.pdf`` and ``.png``), each with its title, and
    table stems (``.csv``, ``.md`` and ``.tex``), under the folders the rule gives it.

    A figure's title is the notebook's heading above it (``## Figure <n>: <title>``, n from
    the stem's ``figNN``) and its label in the Snakemake report, so both say the same."""

    figures: Mapping[str, str] = field(default_factory=dict)
    tables: tuple[str, ...] = ()
    reads: tuple[str, ...] = ()
    """The config sections it reads (its job file, ``cape.workflow.job_files``)."""


READS_RUNS = ("tracks", "data", "reference", "controllers", "models", "study")
"""The config sections of a notebook that draws runs on the track."""

STUDY_NOTEBOOKS: dict[str, NotebookOutputs] = {
    "closed_loop": NotebookOutputs(
        figures={
            "fig02_signals_eta0": "vx, vy, ω, T, δ at η = 0 (first seed)",
            "fig03_tracking_error_sweep": "tracking error over the η sweep",
            "fig07_ex_time_eta0": "e_x over time at η = 0 (first seed)",
            "fig08_ey_time_eta0": "e_y over time at η = 0 (first seed)",
            "fig09_trajectories_eta0": "trajectories on ETHZMobil at η = 0 (first seed)",
            "fig10_penalised_errors_sweep": "failure-penalised tracking errors over the η sweep",
            "fig11_penalised_lap_time": (
                "failure-penalised lap time, every model × controller (mean over η)"
            ),
        },
        tables=("table06_metrics_eta1", "table07_success"),
        reads=READS_RUNS,
    ),
    "bicycle": NotebookOutputs(
        figures={
            "fig05_bicycle_errors": (
                "failure-penalised tracking errors, bicycle variants vs learned EPM"
            ),
            "fig06_bicycle_lap_time": "failure-penalised lap time, bicycle variants vs learned EPM",
        },
        tables=("table05_best_bicycle_controller",),
        reads=("controllers", "models", "study"),
    ),
    "ablation": NotebookOutputs(
        figures={
            "fig04_ablation_trajectories": (
                "trajectories at η = 0 (first seed), internal model vs plant"
            )
        },
        reads=READS_RUNS,
    ),
    "failures": NotebookOutputs(
        figures={"fig12_failure_locations": "failure locations"}, reads=READS_RUNS
    ),
}
"""Per-study notebooks: the one of the study's kind, and ``failures`` for every study."""

WHOLE_STUDY_NOTEBOOKS: dict[str, NotebookOutputs] = {
    "setup": NotebookOutputs(
        figures={"fig01_block_diagram": "the closed loop of every run"},
        tables=("table02_controller_parameters", "table03_uncertainty_activation"),
        reads=("controllers", "disturbances", "models"),
    ),
    "scorecard": NotebookOutputs(
        figures={
            "fig13_claim_effects": (
                "each closed-loop claim's effect with its 95 % interval, per training draw "
                "(over its seeds) and over the draws, beside the paper's"
            ),
            "fig14_leaderboard": (
                "each model's effect against the reference model with its 95 % interval, one "
                "panel per study (table 9)"
            ),
        },
        tables=(
            "table08_scorecard",
            "table09_leaderboard",
            "table04_replicates",
            "table04_trainings",
            "table04_reliability",
            "table01_replicates",
        ),
        reads=(*READS_RUNS, "training", "scorecard"),
    ),
    "question": NotebookOutputs(
        figures={
            "fig15_question_looks": (
                "the ground-truth question: each row's intervals at each look against zero and "
                "its margin, and where it stopped"
            )
        },
        tables=("table10_question",),
    ),
}
"""Notebooks of the whole study (their outputs directly under results/figures, results/tables;
the question's under results/question/)."""


def declared(name: str) -> bool:
    """True if ``name`` is a figure or table some notebook declares."""
    every = [*STUDY_NOTEBOOKS.values(), *WHOLE_STUDY_NOTEBOOKS.values()]
    return any(name in n.figures or name in n.tables for n in every)


def figure_heading(name: str, title: str) -> str:
    """The heading a notebook puts above figure ``name`` ("Figure 2: …" for ``fig02_…``)."""
    return f"Figure {int(name[3:5])}: {title}"
