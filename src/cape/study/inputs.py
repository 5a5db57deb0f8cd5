"""The files the scorecard reads besides the runs: a table of the model stage per training
draw, and each draw's training record (loss.csv, meta.json) for the health checks."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import pandas as pd


def read_replicate_tables(paths: str | Sequence[str]) -> dict[int, pd.DataFrame]:
    """Replicate → table, from ``results/tables/rep<r>/<table>.csv`` paths (comma-separated in
    a notebook's parameter)."""
    items = paths.split(",") if isinstance(paths, str) else list(paths)
    tables = {}
    for item in (p for p in items if p):
        match = re.fullmatch(r"rep([0-9]+)", Path(item).parent.name)
        if match is None:
            raise ValueError(f"{item}: not a replicate's table (…/rep<r>/<table>.csv)")
        tables[int(match.group(1))] = pd.read_csv(item)
    return tables


def read_trainings(
    model_root: str, replicates: Sequence[int], models: Sequence[str]
) -> tuple[dict[tuple[int, str], pd.DataFrame], dict[tuple[int, str], float]]:
    """(replicate, model) → loss.csv and → meta.json's best validation loss, for the training
    checks of ``cape.models.health``."""
    from cape.models.trained import read_training

    losses, best = {}, {}
    for r in replicates:
        for m in models:
            losses[(r, m)], meta = read_training(Path(model_root, f"rep{r}", m))
            best[(r, m)] = float(meta["best_val_loss"])
    return losses, best
