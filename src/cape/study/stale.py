"""An aggregation whose runs are not all there: said when the workflow starts.

Snakemake rebuilds a deleted file only when a target it was asked for names it; a job whose
output exists and some of whose inputs are missing is not run again. The default target and
`replicates` name every file of every job they comprise, so rerunning them recomputes a deleted
run and then the aggregation. Asked for ``runs.parquet`` alone, Snakemake would leave it listing
runs that are gone: the workflow's main process says so, with the command that rebuilds them.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path


def missing_runs(aggregate: str | Path, run_files: Iterable[str | Path]) -> list[Path]:
    """The run files missing beside an existing ``aggregate`` (none when it does not exist)."""
    if not Path(aggregate).is_file():
        return []
    return [Path(f) for f in run_files if not os.path.exists(f)]
