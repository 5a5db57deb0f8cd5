"""What the figure notebooks share: loading the config, the runs and the summary, labels,
the folder of one run, and writing tables and figures where the workflow expects them.

Each figure and table a notebook saves is also shown in it, as saved: the executed notebooks
and their HTML copies are where a user sees the results and how they were made.
"""

from __future__ import annotations

import base64
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from cape.config import config_from_args
from cape.errors import CapeError
from cape.layout import paths
from cape.layout.record import read_series
from cape.layout.runs import RunId
from cape.plots.style import PNG_DPI, save_figure
from cape.specs.notebook import NotebookSpec
from cape.specs.study import StudySpec
from cape.storage.tables import number_formats, to_html, to_markdown, write_table
from cape.study.reports.outputs import declared

SCREEN_DPI = 100
"""CSS pixels per figure inch at which a notebook shows a figure: matplotlib's own screen
resolution (the size ``<Figure size 1260x890>`` names), where 10-point labels are about as
large as the page's text. A page narrower than that scales the image down to fit."""


def enter_repository() -> None:
    """Opened by hand from notebooks/, a notebook works from the repository root like the
    workflow does (its default paths are relative to it)."""
    if Path.cwd().name == "notebooks" and (Path.cwd().parent / "Snakefile").is_file():
        os.chdir(Path.cwd().parent)


def load_spec(spec: str = "") -> NotebookSpec:
    """The job specification file papermill passed, else config/config.yaml, typed."""
    return NotebookSpec.from_config(config_from_args(None, None, spec or None))


def nothing_here(runs: pd.DataFrame, study_spec: StudySpec | None, study: str) -> str:
    """Why this target holds no run of ``study`` to draw ('' when it holds some): a notebook
    with nothing to draw says so in each figure and table it writes (``nothing_to_draw``,
    ``nothing_table``) instead of failing inside Matplotlib."""
    if len(runs):
        return ""
    grid = None if study_spec is None else study_spec.studies.get(study)
    if grid is None:
        return f"the config has no study {study!r}"
    which = (
        "every training draw"
        if grid.replicates == "all"
        else "training draw(s) " + ", ".join(str(r) for r in grid.replicates)
    )
    return (
        f"this target holds no run of the {study} study, which runs for {which}; the default "
        "target reads draw 0, `snakemake --cores 2 replicates` reads every draw"
    )


def nothing_table(why: str) -> pd.DataFrame:
    """A table that says why it is empty (see ``nothing_here``)."""
    return pd.DataFrame({"nothing to show": [why]})


def run_dir(root: str | Path, row: Mapping[str, Any]) -> Path:
    """The folder of the run described by ``row`` of runs.parquet: where it was computed (a run
    two studies share lives in one of their folders), else the one its identity names."""
    if "folder" in row and isinstance(row["folder"], str):
        return Path(row["folder"])
    run = RunId(str(row["study"]), str(row["plant"]), str(row["internal"]),
                str(row["controller"]), str(row["eta_label"]), int(row["seed"]),
                int(row.get("replicate", 0)))  # fmt: skip
    return run.folder(root)


def run_series(row: Mapping[str, Any], series_paths: str = "") -> pd.DataFrame:
    """The time series of the run described by ``row``, checked against the digest its
    metrics recorded (a damaged run is one message naming its folder, not a traceback).
    ``series_paths``: the series files the notebook's rule declares (comma-separated); a run
    whose series is not among them is refused, since the workflow does not make it for this
    notebook. Empty (a notebook run by hand): any run under ``results/runs``."""
    folder = run_dir(paths.RUNS, row)
    declared_files = [item for item in series_paths.split(",") if item]
    if declared_files and str(folder / paths.SERIES) not in declared_files:
        raise CapeError(
            f"{folder}: the notebook reads this run's series, but its rule does not declare it "
            "(cape.workflow.runs.Runs.example_series); add it there"
        )
    return read_series(folder)


def series_of(runs: pd.DataFrame, series_paths: str = "") -> dict[tuple[str, str], pd.DataFrame]:
    """(model, controller) → the time series of each run in ``runs`` (one per pair)."""
    return {
        (row["model"], row["controller"]): run_series(row, series_paths)
        for _, row in runs.iterrows()
    }


def _declared(stem: str) -> None:
    """A figure or table must be declared in cape.study.reports.outputs (what the rules build)."""
    name = Path(stem).name
    if not declared(name):
        raise CapeError(
            f"{name}: not declared in cape/study/reports/outputs.py; add it to its notebook's "
            "entry there, so that the workflow knows the file"
        )


def _show(data: dict[str, str], metadata: dict[str, Any] | None = None) -> None:
    """Publish ``data`` (MIME type → content) as an output of the running notebook cell.

    Only in an IPython session: the same ``save`` from a script or a test just writes files
    (and cape does not need IPython installed for that)."""
    try:
        from IPython import get_ipython
        from IPython.display import display
    except ImportError:
        return
    if get_ipython() is not None:
        display(data, raw=True, metadata=metadata or {})


def show_table(frame: pd.DataFrame) -> None:
    """Show ``frame`` in the notebook as its .md and .tex copies print it (four significant
    digits, a dash for a missing value, no row index), not as pandas would (NaN, six decimals)."""
    formats = number_formats(frame)
    _show({"text/html": to_html(frame, formats), "text/plain": to_markdown(frame, formats)})


def save_table(frame: pd.DataFrame, stem: str, latex: bool = True) -> None:
    """``stem``.csv (full precision) and .md (and .tex, four significant digits), atomically;
    the table is then shown in the notebook as the .md prints it."""
    _declared(stem)
    paths = [f"{stem}.csv", f"{stem}.md"] + ([f"{stem}.tex"] if latex else [])
    write_table(frame, paths, formats=number_formats(frame))
    show_table(frame)


def _png_width(png: bytes) -> int:
    """A PNG's width in pixels, from its header (the IHDR chunk follows the 8-byte signature)."""
    if png[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError("not a PNG file")
    return int.from_bytes(png[16:20], "big")


def show_png(path: str | Path, dpi: int = PNG_DPI) -> None:
    """Show the PNG file at ``path``, saved at ``dpi``, in the notebook: the very bytes of the
    file (the figure the notebook saved, not a second rendering of it), at ``SCREEN_DPI``."""
    png = Path(path).read_bytes()
    width = round(_png_width(png) * SCREEN_DPI / dpi)
    _show(
        {"image/png": base64.b64encode(png).decode("ascii"), "text/plain": f"<figure {path}>"},
        {"image/png": {"width": width}},
    )


def save(fig: Any, stem: str) -> None:
    """``stem``.pdf and .png, then the PNG shown in the notebook: a notebook cannot save a
    figure without showing it (Agg, the backend of every figure, has no inline display)."""
    _declared(stem)
    Path(stem).parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, f"{stem}.pdf", f"{stem}.png", dpi=PNG_DPI)
    show_png(f"{stem}.png", dpi=PNG_DPI)
