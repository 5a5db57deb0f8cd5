"""What the figure notebooks share: loading the config, the runs and the summary, labels,
the folder of one run, and writing tables and figures where the workflow expects them."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from cape.config import config_from_args
from cape.errors import CapeError
from cape.plots.style import save_figure
from cape.study.grid import RunId
from cape.study.outputs import declared
from cape.study.record import read_series
from cape.tables import write_table


def enter_repository() -> None:
    """Opened by hand from notebooks/, a notebook works from the repository root like the
    workflow does (its default paths are relative to it)."""
    if Path.cwd().name == "notebooks" and (Path.cwd().parent / "Snakefile").is_file():
        os.chdir(Path.cwd().parent)


def load_config(config_json: str = "") -> dict[str, Any]:
    """The sections papermill passed as JSON, else config/config.yaml."""
    return config_from_args(None, config_json or None)


def controller_labels(config: Mapping[str, Any]) -> dict[str, str]:
    return {name: str(entry.get("label", name)) for name, entry in config["controllers"].items()}


def run_dir(root: str | Path, row: Mapping[str, Any]) -> Path:
    """The folder of the run described by ``row`` of runs.parquet: where it was computed (a run
    two studies share lives in one of their folders), else the one its identity names."""
    if "folder" in row and isinstance(row["folder"], str):
        return Path(row["folder"])
    run = RunId(str(row["study"]), str(row["plant"]), str(row["internal"]),
                str(row["controller"]), str(row["eta_label"]), int(row["seed"]))  # fmt: skip
    return run.folder(root)


def run_series(root: str | Path, row: Mapping[str, Any]) -> pd.DataFrame:
    """The time series of the run described by ``row``, checked against the digest its
    metrics recorded (a damaged run is one message naming its folder, not a traceback)."""
    return read_series(run_dir(root, row))


def series_of(root: str | Path, runs: pd.DataFrame) -> dict[tuple[str, str], pd.DataFrame]:
    """(model, controller) → the time series of each run in ``runs`` (one per pair)."""
    return {(row["model"], row["controller"]): run_series(root, row) for _, row in runs.iterrows()}


def _number(value: Any) -> str:
    """Four significant digits; a missing value (no CI from one seed, no lap) as a dash."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def _declared(stem: str) -> None:
    """A figure or table must be declared in cape.study.outputs (what the rules build)."""
    name = Path(stem).name
    if not declared(name):
        raise CapeError(
            f"{name}: not declared in cape/study/outputs.py; add it to its notebook's entry "
            "there, so that the workflow knows the file"
        )


def save_table(frame: pd.DataFrame, stem: str, latex: bool = True) -> None:
    """``stem``.csv (full precision) and .md (and .tex, four significant digits), atomically."""
    _declared(stem)
    paths = [f"{stem}.csv", f"{stem}.md"] + ([f"{stem}.tex"] if latex else [])
    floats = frame.select_dtypes("number").columns
    write_table(frame, paths, formats=dict.fromkeys(floats, _number))


def save(fig: Any, stem: str) -> None:
    """``stem``.pdf and .png."""
    _declared(stem)
    Path(stem).parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, f"{stem}.pdf", f"{stem}.png")
