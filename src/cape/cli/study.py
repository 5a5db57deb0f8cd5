"""``cape aggregate``: every run's metrics in one table and the per-cell summaries (SPEC §8–§9);
``cape replicates``: the replicated study's tables 8 and 9 published, or re-derived.

Each command's arguments are defined right above it (``@command``)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from cape.cli.common import (
    DRAW,
    _add_config_args,
    _config,
    claim,
    command,
)
from cape.errors import CapeError
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
    claim(args, Output(Path(args.out), "table of runs", made, suffixes=(".parquet",)),
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


def _replicates_arguments(p: argparse.ArgumentParser) -> None:
    action = p.add_mutually_exclusive_group(required=True)
    action.add_argument(
        "--publish",
        metavar="FOLDER",
        help="copy the replicated study's tables 8 and 9, RESULTS.md, figures 13–14 and its "
        "evidence into FOLDER, with provenance.json (e.g. docs/results/replicates)",
    )
    action.add_argument(
        "--from",
        dest="source",
        metavar="FOLDER",
        help="re-derive tables 8 and 9 from a published FOLDER's evidence alone and compare "
        "them with its tables",
    )
    p.add_argument(
        "--scope",
        default=paths.REPLICATES_SCOPE,
        help="the scope to publish (%(default)s; results/ for the default target's draw 0)",
    )
    p.add_argument(
        "--configfile",
        nargs="+",
        default=[],
        metavar="FILE",
        help="config files over config/config.yaml, as given to snakemake (for the provenance)",
    )


@command(
    "replicates",
    "publish the replicated study's claims and leaderboard, or re-derive a published one",
    _replicates_arguments,
)
def cmd_replicates(args: argparse.Namespace) -> None:
    from cape.study.reports import study_publish as publish

    if args.source:
        folder = Path(args.source)
        derived = publish.rederive(folder)
        wrong = publish.differences(folder, derived)
        if wrong:
            raise CapeError(
                f"{folder}: the re-derivation from evidence/ differs in {len(wrong)} place(s), "
                f"first {wrong[0]}; the published data do not give the published tables"
            )
        rows = ", ".join(f"{Path(name).name} {len(t)} rows" for name, t in derived.items())
        print(f"cape replicates --from {folder}: {rows} re-derived from evidence/; every "
              f"verdict equal, numbers within {publish.NUMERIC_TOLERANCE:g}")  # fmt: skip
        return
    from cape.config import DEFAULT_CONFIG, merged_config
    from cape.storage.ownership import Output

    folder = Path(args.publish)
    config = merged_config([str(DEFAULT_CONFIG), *args.configfile])
    names = [*publish.COPIED, paths.STUDY_PROVENANCE]
    claim(args, *(Output(folder / n, "published study", option="--publish") for n in names))
    written = publish.publish(args.scope, folder, config)
    print(f"cape replicates --publish: {len(written)} files in {folder}; check them with "
          f"`cape replicates --from {folder}`")  # fmt: skip
