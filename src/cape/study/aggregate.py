"""Every run's metrics in one tidy table (``runs.parquet``), and summaries over seeds.

A run is identified by (study, replicate, plant, internal, controller, eta, seed)
(``cape.layout.runs.RunId``). Summaries group the seeds of one cell: a metric's mean with its
95 % Student-t half-width (``_ci``, what the tables print) and that interval intersected with the
range the metric's runs can take (``_lo``, ``_hi``, what the figures draw), the success rate, and
the failure-penalised means of SPEC §5.3. Why the intersected interval: docs/modules.md.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from cape.errors import CapeError
from cape.layout import paths
from cape.layout.names import TRUTH
from cape.layout.record import read_metrics, read_timing, run_fix, verify_series
from cape.layout.runs import RunId
from cape.storage.integrity import KEY

KEYS = ["study", "replicate", "plant", "internal", "controller", "eta", "seed"]
CELL = ["study", "replicate", "model", "plant", "internal", "controller", "eta", "eta_label"]
METRICS = [
    "lap_time",
    "lap_time_penalised",
    "mean_abs_ex",
    "mean_abs_ey",
    "mean_abs_ex_penalised",
    "mean_abs_ey_penalised",
    "mean_abs_cte",
    "mean_speed",
    "mean_abs_dT",
    "mean_abs_ddelta",
    "fallbacks",
    "rescues",
    "solver_iterations_median",
    "solve_ms_median",
]


class CurrentModels:
    """The weights digest of each trained model now in ``root/rep<r>/<model>/`` (read once)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self._seen: dict[tuple[int, str], tuple[Path, str]] = {}

    def __call__(self, replicate: int, model: str) -> tuple[Path, str]:
        key = (replicate, model)
        if key not in self._seen:
            from cape.models.trained import read_meta

            folder = paths.model_under(self.root, model, replicate)
            self._seen[key] = (folder / paths.META, str(read_meta(folder).get("weights_sha256")))
        return self._seen[key]


def check_models(metrics: Mapping[str, Any], folder: Path, current: CurrentModels) -> None:
    """A run must record the trained networks it was computed with, and they must be its
    replicate's current models (cape.closedloop.provenance)."""
    fix = f"the run is stale: {run_fix(folder)}"
    recorded = metrics.get("models")
    plant = str(metrics["plant"])
    if recorded is None:
        if plant != TRUTH or str(metrics["internal"]) != TRUTH:
            raise CapeError(
                f"{folder}: metrics.json records no trained networks (written by an earlier "
                f"version of `cape rollout`); {fix}"
            )
        return
    if plant != TRUTH and "plant" not in recorded:
        raise CapeError(f"{folder}: metrics.json records no network for its plant {plant}; {fix}")
    replicate = int(metrics["replicate"])
    for role, used in recorded.items():
        meta, digest = current(replicate, str(used["model"]))
        if used.get("replicate") != replicate or used.get("weights_sha256") != digest:
            found = str(used.get("weights_sha256"))[:12]
            raise CapeError(
                f"{folder}: its {role} model {used['model']} was {used['folder']} (draw "
                f"{used.get('replicate')}, weights {found}…), but draw {replicate}'s is "
                f"{meta.parent} (weights {digest[:12]}…, {meta}); {fix}"
            )


def read_run(
    metrics_path: Path,
    study: str | None = None,
    expected: RunId | None = None,
    replicate: int | None = None,
    current: CurrentModels | None = None,
) -> dict:
    """One row of ``study`` (default: the study the run's metrics.json records): the run's
    metrics and its timing (a run shared by two studies is read once per study). The run's
    files are checked first (``cape.layout.record``): its metrics against their schema, their
    checksum and the run ``expected`` (default: the one the folder names), its timing against
    its checksum, its series against the digest the timing recorded. ``replicate``: the
    replicate of the study that asks (the run's own: draws share no run, SPEC §10 revision
    7)."""
    metrics = read_metrics(metrics_path, expected)
    folder = metrics_path.parent
    timing = read_timing(folder)
    verify_series(folder, timing)
    timing = {k: v for k, v in timing.items() if k.startswith("solve_ms")}
    if current is not None:
        check_models(metrics, folder, current)
    kept = {k: v for k, v in metrics.items() if k not in (KEY, "models")}
    row = {**kept, **timing, "study": study or metrics["study"], "folder": str(folder)}
    if replicate is not None:
        row["replicate"] = replicate
    row["eta_label"] = str(row["eta"])
    row["eta"] = float(row["eta"])
    return row


def collect_runs(
    runs: Iterable[tuple[Any, ...]],
    varies_internal: Collection[str],
    models_root: str | Path | None = None,
) -> pd.DataFrame:
    """The tidy table of the given runs ((study, metrics.json[, the run it must hold[, the
    replicate that asks]]) tuples; a study of None: the one the run records), sorted by its keys;
    ``models_root``: check each run's trained networks against the models there.
    ``model`` names the model a run is about: the internal model in a study that varies it (the
    ground-truth study: ``varies_internal``, ``StudySpec.internal_studies``), else the
    plant's."""
    current = CurrentModels(models_root) if models_root is not None else None
    rows = [read_run(Path(run[1]), run[0], *run[2:4], current=current) for run in runs]
    if not rows:
        raise CapeError("no runs to aggregate")
    _refuse_twice(rows)
    frame = pd.DataFrame(rows)
    by_internal = frame["study"].isin(list(varies_internal))
    frame["model"] = frame["internal"].where(by_internal, frame["plant"])
    first = [*KEYS, "model", "eta_label", "success", "failure", "steps"]
    frame = frame[first + [c for c in frame.columns if c not in first]]
    return frame.sort_values(KEYS, kind="stable").reset_index(drop=True)


def _refuse_twice(rows: Sequence[Mapping[str, Any]]) -> None:
    """Each run counts once: a metrics.json given twice (the same file, or a copy of the same
    run elsewhere) would weigh its run double in every mean and interval. A user who lists a
    run twice has made a mistake, so it is refused rather than silently counted once. (A run
    the grid reads for two studies or replicates is two rows of different keys.)"""
    seen: dict[tuple[Any, ...], str] = {}
    for row in rows:
        key = tuple(row[k] for k in KEYS)
        path = str(Path(row["folder"]) / paths.METRICS)
        if key not in seen:
            seen[key] = path
            continue
        first = seen[key]
        run = ", ".join(f"{k} {row[k]}" for k in KEYS)
        said = (
            f"{path}: given twice"
            if Path(first).resolve() == Path(path).resolve()
            else f"{path}: the same run as {first}"
        )
        raise CapeError(f"{said} ({run}); each run counts once: list it once")


def mean_ci(values: Sequence[float], level: float = 0.95) -> tuple[float, float, float]:
    """Mean and the half-width of its confidence interval (NaN half-width for one value)."""
    x = np.asarray([v for v in values if v is not None and not math.isnan(v)], dtype=float)
    if x.size == 0:
        return math.nan, math.nan, 0
    if x.size == 1:
        return float(x[0]), math.nan, 1
    half = stats.t.ppf(0.5 + level / 2, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size)
    return float(x.mean()), float(half), int(x.size)


def support(metric: str, group: pd.DataFrame) -> tuple[float, float]:
    """The range the per-run values of ``metric`` can take in one cell (see the module's
    docstring): [0, ∞), and for the penalised lap time [0, max(time limit, largest value)]
    (the largest value is the penalty when a run failed)."""
    if metric == "lap_time_penalised" and "time_limit" in group:
        values = group[[metric, "time_limit"]].to_numpy(dtype=float)
        if np.isfinite(values).any():
            return 0.0, float(np.nanmax(values))
    return 0.0, math.inf


def summarise(runs: pd.DataFrame, by: Sequence[str] = CELL, level: float = 0.95) -> pd.DataFrame:
    """Per cell: runs, successes, success rate, and for every metric its mean, CI half-width
    and the CI bounded by the metric's range (``<metric>_mean``, ``_ci``, ``_lo``, ``_hi``, over
    the runs where it exists: successful laps for the plain lap time, every run for the
    penalised values)."""
    rows = []
    for key, group in runs.groupby(list(by), sort=True, dropna=False):
        row = dict(zip(by, key if isinstance(key, tuple) else (key,), strict=True))
        row["runs"] = len(group)
        row["successes"] = int(group["success"].sum())
        row["success_rate"] = row["successes"] / len(group)
        for metric in METRICS:
            if metric not in group:
                continue
            values = group[metric].to_numpy(dtype=float)
            mean, half, n = mean_ci(values, level)
            row[f"{metric}_mean"], row[f"{metric}_ci"], row[f"{metric}_n"] = mean, half, n
            low, high = support(metric, group)
            spread = 0.0 if math.isnan(half) else half
            row[f"{metric}_lo"] = max(mean - spread, low) if n else math.nan
            row[f"{metric}_hi"] = min(mean + spread, high) if n else math.nan
        rows.append(row)
    return pd.DataFrame(rows)
