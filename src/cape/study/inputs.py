"""The files the scorecard reads besides the runs: a table of the model stage per training
draw, and each draw's training record (loss.csv, meta.json) for the health checks."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from cape.errors import CapeError
from cape.layout import paths
from cape.storage.io import read_csv


def read_replicate_tables(
    replicates: str | Sequence[int],
    table_paths: str | Sequence[str],
    model_root: str | Path | None = None,
) -> dict[int, pd.DataFrame]:
    """Replicate → table: ``table_paths[i]`` is draw ``replicates[i]``'s (comma-separated in
    a notebook's parameters). With ``model_root``, each row must have been computed from its
    replicate's current model in ``model_root/rep<r>/<model>`` (the table's ``replicate`` and
    ``weights_sha256`` columns, written by ``cape openloop`` and ``cape complexity``);
    ``CapeError`` names the table, the model and the fix otherwise."""
    draws = [int(r) for r in _items(replicates)]
    items = [str(p) for p in _items(table_paths)]
    if len(draws) != len(items):
        raise CapeError(
            f"{len(items)} table(s) for {len(draws)} draw(s) ({', '.join(map(str, draws))}):"
            " give one table per draw, in the same order"
        )
    tables = {}
    for replicate, item in zip(draws, items, strict=True):
        table = read_csv(
            item,
            f"build it (snakemake --cores 2 {item})",
            "unreadable ({reason}); delete it and rebuild it",
        )
        if model_root is not None:
            check_table_models(table, item, replicate, Path(model_root))
        tables[replicate] = table
    return tables


def _items(value: str | Sequence[Any]) -> list[Any]:
    return [p for p in value.split(",") if p] if isinstance(value, str) else list(value)


def check_table_models(table: pd.DataFrame, path: str, replicate: int, model_root: Path) -> None:
    """Every row of the replicate's table ``path`` was computed from the model now in
    ``model_root/rep<replicate>/<model>`` (same training replicate, same weights digest)."""
    from cape.models.trained import read_meta

    fix = f"the table is stale: delete it and rebuild it (snakemake --cores 2 {path})"
    if "model" not in table.columns:
        raise CapeError(f"{path}: has no model column; {fix}")
    if not {"replicate", "weights_sha256"} <= set(table.columns):
        raise CapeError(
            f"{path}: records no model weights (written by an earlier version of cape); {fix}"
        )
    for row in table.itertuples(index=False):
        folder = paths.model_under(model_root, str(row.model), replicate)
        digest = str(read_meta(folder).get("weights_sha256") or "")
        made, found = row.replicate, str(row.weights_sha256)
        if pd.isna(made) or int(made) != replicate or found != digest:
            raise CapeError(
                f"{path}: its {row.model} row was computed from draw {made}'s network "
                f"(weights {found[:12]}…), but draw {replicate}'s is {folder} (weights "
                f"{digest[:12]}…); {fix}"
            )


def read_draws(
    model_root: str, replicates: Sequence[int], models: Sequence[str]
) -> dict[tuple[int, str], dict]:
    """(replicate, model) → the draw's meta.json (its training, its health and the trainings
    it was chosen among: ``cape draw``), for cape.training.health's tables."""
    from cape.models.trained import read_meta

    draws = [(r, m) for r in replicates for m in models]
    return {(r, m): read_meta(paths.model_under(model_root, m, r)) for r, m in draws}
