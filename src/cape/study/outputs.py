"""Every table and figure of the study, declared once: which notebook writes it, and for which
kind of study (SPEC §9).

The workflow's rules read these lists for their outputs; the notebooks' ``save`` and
``save_table`` refuse a name that is not declared here. So a new figure is one entry below plus
the notebook cell that draws it.

A study's kind (``study.studies.<name>.kind`` in the config) says which notebook draws it:
``closed_loop`` (the default: the learned and ground-truth studies, or one a user adds),
``bicycle`` (fixed-parameter plants against the paper's study) or ``ablation`` (internal model
against plant). Every study also gets the failure map, and the whole study the set-up figures
and the scorecard.
"""

from __future__ import annotations

from dataclasses import dataclass

KINDS = ("closed_loop", "bicycle", "ablation")


@dataclass(frozen=True)
class NotebookOutputs:
    """What one notebook writes: figure stems (``.pdf`` and ``.png``) and table stems (``.csv``,
    ``.md`` and ``.tex``), under the folders the rule gives it."""

    figures: tuple[str, ...] = ()
    tables: tuple[str, ...] = ()


STUDY_NOTEBOOKS: dict[str, NotebookOutputs] = {
    "closed_loop": NotebookOutputs(
        figures=(
            "fig02_signals_eta0",
            "fig03_tracking_error_sweep",
            "fig07_ex_time_eta0",
            "fig08_ey_time_eta0",
            "fig09_trajectories_eta0",
            "fig10_penalised_errors_sweep",
            "fig11_penalised_lap_time",
        ),
        tables=("table06_metrics_eta1", "table07_success"),
    ),
    "bicycle": NotebookOutputs(
        figures=("fig05_bicycle_errors", "fig06_bicycle_lap_time"),
        tables=("table05_best_bicycle_controller",),
    ),
    "ablation": NotebookOutputs(figures=("fig04_ablation_trajectories",)),
    "failures": NotebookOutputs(figures=("fig12_failure_locations",)),
}
"""Per-study notebooks: the one of the study's kind, and ``failures`` for every study."""

WHOLE_STUDY_NOTEBOOKS: dict[str, NotebookOutputs] = {
    "setup": NotebookOutputs(
        figures=("fig01_block_diagram",),
        tables=("table02_controller_parameters", "table03_uncertainty_activation"),
    ),
    "scorecard": NotebookOutputs(tables=("table08_scorecard",)),
}
"""Notebooks of the whole study (their outputs directly under results/figures, results/tables)."""


def declared(name: str) -> bool:
    """True if ``name`` is a figure or table some notebook declares."""
    every = [*STUDY_NOTEBOOKS.values(), *WHOLE_STUDY_NOTEBOOKS.values()]
    return any(name in n.figures or name in n.tables for n in every)


def notebooks_of(kind: str) -> tuple[str, ...]:
    """The per-study notebooks a study of ``kind`` gets."""
    return (kind, "failures")
