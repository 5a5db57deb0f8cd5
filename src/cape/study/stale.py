"""An aggregation older than a deletion: rebuilt, never left listing runs that are gone.

Snakemake rebuilds a deleted file only when something it was asked for needs it, and an
existing ``runs.parquet`` does not need its runs again. So the workflow's main process ages a
scope's aggregation whose runs are not all there (its modification time set to the epoch, the
file itself kept): Snakemake then finds it older than its inputs and rebuilds it, recomputing
the missing runs first, whichever target was asked for.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from pathlib import Path


def age_if_incomplete(
    aggregates: Sequence[str | Path], run_files: Iterable[str | Path]
) -> list[Path]:
    """If any of ``run_files`` is missing, set the existing ``aggregates``' modification time
    to the epoch; the missing files (none: nothing was touched)."""
    present = [Path(a) for a in aggregates if Path(a).is_file()]
    if not present:
        return []
    missing = [Path(f) for f in run_files if not os.path.exists(f)]
    if missing:
        for path in present:
            os.utime(path, (0, 0))
    return missing
