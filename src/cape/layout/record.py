"""A run's record on disk: its three files written together, and read back only when intact.

``cape rollout`` writes a run folder (``RUN_FILES``) in one rename; every reader goes through
``read_metrics``, ``read_timing`` and ``read_series``, which refuse a folder whose files do not
fit (schema ``cape/schemas/metrics.schema.yaml``, checksums, run). Every refusal is a
``CapeError`` naming the run folder and the fix (``run_fix``): for one of the workflow's run
folders, `snakemake --force` of its metrics.json (Snakemake replaces exactly that run's files);
for any other folder, that it is no run the workflow made. No refusal suggests deleting a folder:
the one named may be a user's. The checks per file: docs/modules.md.
"""

from __future__ import annotations

import hashlib
import io
import json
from collections.abc import Mapping
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from cape import schemas
from cape.errors import CapeError
from cape.layout import paths
from cape.layout.runs import RunId
from cape.storage.integrity import check_record, sealed_record
from cape.storage.io import write_bytes
from cape.storage.parquet import parquet_bytes

SERIES_KEY = "series_sha256"


def write_run_files(
    folder: Path, metrics: Mapping[str, Any], series: Mapping[str, np.ndarray]
) -> str:
    """``timeseries.parquet`` and ``metrics.json`` (sealed) into ``folder`` (the temporary
    folder of ``cape.storage.io.atomic_folder``); returns the series' digest, which ``write_timing``
    records. The series holds the per-step solve times, wall-clock numbers, so its digest
    goes with the timing, and ``metrics.json`` stays byte-identical across reruns."""
    data = parquet_bytes(series)  # cape.storage.parquet: no pyarrow to import in every rollout job
    write_bytes(folder / paths.SERIES, data)
    text = json.dumps(sealed_record(metrics), indent=2, sort_keys=True) + "\n"
    write_bytes(folder / paths.METRICS, text.encode())
    return hashlib.sha256(data).hexdigest()


def write_timing(folder: Path, timing: Mapping[str, Any], series_sha256: str) -> None:
    """``timing.json`` (sealed), with the digest of the run's series."""
    record = sealed_record({**timing, SERIES_KEY: series_sha256})
    write_bytes(
        folder / paths.TIMING, (json.dumps(record, indent=2, sort_keys=True) + "\n").encode()
    )


def run_fix(folder: Path) -> str:
    """What to do about a run folder whose files do not fit: for one of the workflow's, recompute
    it (`snakemake --force` replaces the rule's own outputs, nothing else); for any other (a file
    at the checkout's root, a user's folder), say that it is no run the workflow made. Never
    "delete": the folder may be the user's (issue 61)."""
    try:
        RunId.parse(folder / paths.METRICS)
    except ValueError:
        layout = "/".join(RunId.wildcards().parts()).replace("{", "<").replace("}", ">")
        return (
            f"the folder {folder} is not one of the workflow's run folders (…/{layout}), so it "
            "holds no run the workflow made and nothing here recomputes it; give the metrics.json "
            "of a run, or make one with `cape rollout --out NEW_FOLDER`"
        )
    return (
        f"recompute that run: `snakemake --cores 1 --force {folder / paths.METRICS}` (Snakemake "
        "replaces the run's own files)"
    )


def _read_json(path: Path, missing: str, fix: str) -> Any:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise CapeError(f"{path}: {missing}") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CapeError(f"{path}: unreadable ({exc}); {fix}") from None


@cache
def _validator() -> Any:
    return schemas.validator(schemas.load_schema(schemas.METRICS))


def read_metrics(path: Path, expected: RunId | None = None) -> dict[str, Any]:
    """A run's ``metrics.json`` (``path``), checked against its schema, its checksum and the
    run ``expected`` (default: the run its folder names, if it names one)."""
    folder = path.parent
    fix = run_fix(folder)
    metrics = _read_json(path, f"missing; run it (`snakemake --cores 1 {path}`)", fix)
    errors = list(_validator().iter_errors(metrics))
    if errors:
        from jsonschema.exceptions import best_match

        first = best_match(errors)  # the field's own type before the rules that depend on it
        field = ".".join(str(p) for p in first.absolute_path) or "(top level)"
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        raise CapeError(
            f"{path}: field `{field}`: {first.message}{more}; not a run's metrics as "
            f"`cape rollout` writes them ({schemas.shown(schemas.METRICS)}); {fix}"
        )
    check_record(metrics, path, fix)
    if expected is None:
        try:
            expected = RunId.parse(folder)
        except ValueError:  # a folder of the user's own (`cape rollout --out DIR`)
            expected = None
    if expected is not None:
        recorded = RunId(
            metrics["study"],
            metrics["plant"],
            metrics["internal"],
            metrics["controller"],
            metrics["eta"],
            metrics["seed"],
            metrics["replicate"],
        )
        if recorded != expected:
            diff = ", ".join(
                f"{k} {getattr(recorded, k)!r} (the folder says {getattr(expected, k)!r})"
                for k in expected.__dataclass_fields__
                if getattr(recorded, k) != getattr(expected, k)
            )
            raise CapeError(f"{path}: the metrics of another run: {diff}; {fix}")
    return metrics


def read_timing(folder: Path) -> dict[str, Any]:
    """A run's ``timing.json``, checked against the checksum it carries: its solve times (None
    where the controller solves nothing) and the digest of its series."""
    path = folder / paths.TIMING
    fix = run_fix(folder)
    timing = _read_json(path, f"missing (the run's files are incomplete); {fix}", fix)
    if not isinstance(timing, dict) or not isinstance(timing.get(SERIES_KEY), str):
        raise CapeError(f"{path}: not a run's timing as `cape rollout` writes it; {fix}")
    for key, value in timing.items():
        if key.startswith("solve_ms") and not (
            value is None or (isinstance(value, int | float) and not isinstance(value, bool))
        ):
            raise CapeError(f"{path}: field `{key}` is {value!r}, not a number or null; {fix}")
    check_record(timing, path, fix)
    return timing


def read_series(folder: Path) -> Any:
    """A run's time series (a pandas DataFrame), checked against the digest in its timing."""
    import pandas as pd

    return pd.read_parquet(io.BytesIO(verify_series(folder, read_timing(folder))))


def verify_series(folder: Path, timing: Mapping[str, Any]) -> bytes:
    """The bytes of a run's ``timeseries.parquet``, refused unless they are the series its
    ``timing.json`` recorded (the aggregation checks every run, so that a damaged run stops
    it, not a notebook)."""
    path, fix = folder / paths.SERIES, run_fix(folder)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise CapeError(f"{path}: missing (the run's files are incomplete); {fix}") from None
    if hashlib.sha256(data).hexdigest() != timing[SERIES_KEY]:
        raise CapeError(
            f"{path}: does not match the digest its timing.json recorded (truncated, damaged "
            f"or replaced since the run); {fix}"
        )
    return data
