"""``cape aggregate``: every run's metrics in one table and the per-cell summaries (SPEC §8–§9).

Each command's arguments are defined right above it (``@command``)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from cape.cli.common import (
    DRAW,
    _add_config_args,
    _claim,
    _config,
    command,
)
from cape.layout import paths


def _aggregate_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("runs", nargs="*", help="metrics.json files of the runs (default: the grid)")
    p.add_argument("--runs-from", metavar="FILE", help="a file listing metrics.json paths")
    p.add_argument("--root", default=paths.RUNS, help="where the grid's runs are (%(default)s)")
    p.add_argument(
        "--replicates",
        type=DRAW,
        nargs="+",
        metavar="R",
        help="only the grid's runs of these draws (default: all)",
    )
    p.add_argument("--out", required=True, help="the tidy table of runs (.parquet)")
    p.add_argument("--summary", required=True, help="the per-cell summary (.parquet)")
    p.add_argument(
        "--models-root",
        help="check each run's trained networks against the models in MODELS_ROOT/rep<r>/ (the "
        "workflow's: results/models); a run computed with others is refused",
    )
    _add_config_args(p)


@command(
    "aggregate",
    "every run's metrics in one table, and per-cell means with 95%% CIs",
    _aggregate_arguments,
)
def cmd_aggregate(args: argparse.Namespace) -> None:
    from cape.specs.study import StudySpec
    from cape.storage.io import write_files
    from cape.storage.ownership import Output
    from cape.study.aggregate import collect_runs, summarise
    from cape.study.grid import study_grid

    spec = StudySpec.from_config(_config(args))
    named = [Path(p) for p in args.runs]
    if args.runs_from:
        named += [Path(line) for line in Path(args.runs_from).read_text().split() if line]
    pairs: list[tuple[Any, ...]]
    if named:  # the runs named, each of the study its metrics.json records
        pairs = [(None, p) for p in named]
    else:  # every run of the config's grid, read where it was computed
        grid = study_grid(spec)
        read = args.replicates
        pairs = [(run.study, computed.folder(args.root) / paths.METRICS, computed, run.replicate)
                 for run, computed in grid.items()
                 if read is None or run.replicate in read]  # fmt: skip
    made = _made_from_runs(pairs, spec, args.models_root)
    _claim(args, Output(Path(args.out), "table of runs", made, suffixes=(".parquet",)),
           Output(Path(args.summary), "summary of cells", made, suffixes=(".parquet",),
                  option="--summary"))  # fmt: skip
    runs = collect_runs(pairs, spec.internal_studies(), args.models_root)
    summary = summarise(runs)
    # both tables or neither: a new runs.parquet never stands beside an old summary
    write_files(
        {args.out: runs.to_parquet(index=False), args.summary: summary.to_parquet(index=False)}
    )
    ok = int(runs["success"].sum())
    print(f"{len(runs)} runs ({ok} laps, {len(runs) - ok} failures) → {args.out}; "
          f"{len(summary)} cells → {args.summary}")  # fmt: skip


def _made_from_runs(pairs: list[tuple[Any, ...]], spec: Any, models_root: str | None) -> str:
    """The identity of an aggregation: how many runs, and one digest of which runs (their
    metrics files, the studies they are read for), the grid's settings and the models root."""
    import hashlib
    import os

    from cape.specs import digest

    lines = sorted(f"{pair[0]}|{os.path.abspath(pair[1])}" for pair in pairs)
    lines += [digest(spec), str(models_root)]
    made = hashlib.sha256("\n".join(lines).encode()).hexdigest()[:16]
    return f"of {len(pairs)} runs [{made}]"
