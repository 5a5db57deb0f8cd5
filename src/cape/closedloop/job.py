"""One run of the grid, from its names to its record: what ``cape rollout`` does between
parsing its arguments and writing the run's folder.

``run_job`` checks the names, records which trained networks the run uses
(``cape.closedloop.provenance``), assembles the run (``cape.closedloop.setup``), drives the lap
and returns a ``RunFiles``: the metrics (byte-reproducible: ``metrics.json``), the timing
(wall-clock numbers: ``timing.json``) and the time series. The job's phases are timed from
``started``, the moment the process began.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cape.closedloop.provenance import run_models
from cape.closedloop.setup import ModelFolders, build_run
from cape.config import check_eta
from cape.controllers import controller_class
from cape.errors import CapeError
from cape.layout.names import check_name
from cape.layout.runs import RunId
from cape.specs.run import RunSpec


@dataclass
class RunFiles:
    """A finished run: ``metrics.json``'s content, ``timing.json``'s (less the writing, which
    the writer times: ``finish_timing``) and the series."""

    metrics: dict[str, Any]
    timing: dict[str, Any]
    series: Mapping[str, np.ndarray]
    lapped: float = field(default=0.0, repr=False)
    """``time.perf_counter()`` when the lap ended: where the write phase starts."""

    def finish_timing(self) -> dict[str, Any]:
        """The timing with the write phase (now − the lap's end) filled in."""
        self.timing["job_s"]["write"] = round(time.perf_counter() - self.lapped, 4)
        return self.timing


def percentile(ordered: Any, q: float) -> float:
    """``np.percentile(values, q)`` (linear interpolation) of already sorted values, without
    NumPy's, whose first call imports ``numpy.ma`` in every job for four numbers."""
    position = q / 100 * (len(ordered) - 1)
    low = int(position)
    high = min(low + 1, len(ordered) - 1)
    return float(ordered[low] + (ordered[high] - ordered[low]) * (position - low))


def check_run(run: RunId) -> float:
    """η of ``run`` as a number; ``CapeError`` for a seed, replicate, study or η that cannot
    name a run."""
    eta = check_eta(run.eta, "--eta")
    if run.seed < 0:
        raise CapeError(f"--seed {run.seed}: a seed is a non-negative integer")
    if run.replicate < 0:
        raise CapeError(f"--replicate {run.replicate}: a draw is a non-negative integer")
    check_name(run.study, "--study")
    return eta


def run_job(
    spec: RunSpec,
    run: RunId,
    internal: str | None,
    folders: ModelFolders,
    raceline: str | None,
    *,
    validate: bool,
    envelope_data: str | None,
    started: float,
    imported: float,
) -> RunFiles:
    """Run ``run`` (checked by ``check_run``) with ``spec``'s settings and the trained models
    in ``folders``. ``internal``: the controller's internal model as asked for (None: the
    plant's own; the record names the one used); ``validate``: check the controller's settings
    (a job's specification was validated when the workflow started)."""
    eta = check_eta(run.eta, "--eta")
    needs = controller_class(spec.controller, spec.controller_entry).needs_internal_model
    used = run_models(
        spec.models, run.plant, (internal or run.plant) if needs else None, folders, run.replicate
    )
    configured = time.perf_counter()
    assembled = build_run(
        spec,
        run.plant,
        eta,
        run.seed,
        internal,
        folders,
        raceline,
        validate=validate,
        envelope_data=envelope_data,
    )
    built = time.perf_counter()
    result = assembled()
    lapped = time.perf_counter()
    metrics = {
        "study": run.study,
        "plant": run.plant,
        "controller": run.controller,
        "internal": assembled.internal,
        "eta": run.eta,
        "seed": run.seed,
        "replicate": run.replicate,
        "models": used,  # the trained networks it was computed with (cape.closedloop.provenance)
        **result.metrics,
    }
    phases = {
        "startup": imported - started,
        "config": configured - imported,
        "build": built - configured,
        "lap": lapped - built,
    }
    timing = job_timing(result, metrics, phases)
    timing["envelope_data"] = assembled.envelope_source  # what bounded the plant (None: none)
    return RunFiles(metrics, timing, result.series, lapped)


def job_timing(result: Any, metrics: Mapping[str, Any], phases: Mapping[str, float]) -> dict:
    """``timing.json`` of a run but its write phase: the solve times' percentiles (ms), the
    job's wall time by phase (s): start-up (the command's modules and arguments, from the first
    of cape.cli's imports), reading the config, building the run (models, solver), the lap (and
    in it the controller's and the plant's shares); the controller's steps by part (an NMPC's:
    benchmarks/draw_cost.py) and how many of the SQP's failures its rescue solved. What a
    process costs before and after these is what benchmarks/rollout_job.py measures."""
    ms = np.sort(result.solve_ms)
    timing: dict[str, Any] = {
        f"solve_ms_{name}": percentile(ms, q) if ms.size else None
        for name, q in (("median", 50), ("p90", 90), ("p99", 99), ("max", 100))
    }
    timing["job_s"] = {
        **{name: round(seconds, 4) for name, seconds in phases.items()},
        "controller": round(float(np.sum(ms)) / 1e3, 4),
        "plant": round(result.plant_s, 4),
        "steps": int(metrics["steps"]),
        "write": 0.0,  # RunFiles.finish_timing
    }
    timing["controller_s"] = {k: round(v, 4) for k, v in sorted(result.controller_s.items())}
    timing["rescues"] = {
        "tried": int(metrics.get("rescues") or 0),
        "succeeded": result.rescues_succeeded,
    }
    return timing
