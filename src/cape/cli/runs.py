"""``cape build-solver``, ``rollout``, ``plot-rollout``: one closed-loop run and what it
needs (SPEC §5–§7).

Each command's arguments are defined right above it (``@command``)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from cape.cli.common import (
    STARTED,
    _add_config_args,
    _add_model_folders,
    _add_outputs,
    _config,
    _model_folders,
    command,
)
from cape.errors import CapeError
from cape.layout.names import TRUTH

PLANT_KINDS = "dpm|ddm|epm (learned), dpm-fixed|ddm-fixed|epm-fixed, or truth"
RUN_WHAT = "a run's own files (metrics.json, timing.json, timeseries.parquet)"


def _build_solver_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--controller", required=True, help="controller name from the config (nmpc…)")
    p.add_argument("--internal", required=True, help=PLANT_KINDS)
    p.add_argument("--out", required=True, help="record of the compiled library (.json)")
    _add_model_folders(p)
    p.add_argument("--raceline", help="reference .npz (default: results/raceline/<track>.npz)")
    _add_config_args(p)


@command(
    "build-solver",
    "build a controller's NLP for an internal model once, compiling it into the cache",
    _build_solver_arguments,
)
def cmd_build_solver(args: argparse.Namespace) -> None:
    import json

    from cape.closedloop.setup import build_run
    from cape.io import write_text

    config = _config(args)
    run = build_run(
        config,
        TRUTH,  # the plant does not enter the controller's NLP
        args.controller,
        0.0,
        0,
        args.internal,
        _model_folders(args),
        args.raceline,
    )
    libraries = [str(library) for library in run.controller.libraries()]
    library = libraries[0] if libraries else None
    record = {
        "controller": args.controller,
        "internal": args.internal,
        "libraries": libraries,
        "compiled": bool(libraries),
    }
    write_text(args.out, json.dumps(record, indent=2, sort_keys=True) + "\n")
    what = f"compiled {', '.join(libraries)}" if library is not None else "no compiled library"
    print(f"{args.controller} with internal model {args.internal}: {what}")


def _rollout_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--plant", required=True, help=PLANT_KINDS)
    p.add_argument(
        "--controller", required=True, help="controller name from the config (pid, rise, ...)"
    )
    p.add_argument("--eta", required=True, help="disturbance level η (0 … 5)")
    p.add_argument("--seed", required=True, type=int, help="seed of every random draw of the run")
    p.add_argument(
        "--out", required=True, help="output folder (metrics.json, timing.json, timeseries.parquet)"
    )
    p.add_argument(
        "--internal", help="the controller's internal model (default: the plant's model)"
    )
    _add_model_folders(p)
    p.add_argument("--raceline", help="reference .npz (default: results/raceline/<track>.npz)")
    p.add_argument("--study", default="adhoc", help="the study the run belongs to (metrics.json)")
    p.add_argument(
        "--training-data",
        help="the data set whose states bound a learned or fixed-parameter plant (SPEC §5.3; "
        "default: results/data/DYN-PP-<data.train_track>.npz)",
    )
    p.add_argument(
        "--replicate",
        default=0,
        type=int,
        help="the training replicate of the models given by --model (metrics.json; SPEC §4)",
    )
    _add_config_args(p)


def _percentile(ordered: Any, q: float) -> float:
    """``np.percentile(values, q)`` (linear interpolation) of already sorted values, without
    NumPy's, whose first call imports ``numpy.ma`` in every job for four numbers."""
    position = q / 100 * (len(ordered) - 1)
    low = int(position)
    high = min(low + 1, len(ordered) - 1)
    return float(ordered[low] + (ordered[high] - ordered[low]) * (position - low))


@command("rollout", "one closed-loop lap: plant, controller, η, seed (SPEC §5)", _rollout_arguments)
def cmd_rollout(args: argparse.Namespace) -> None:
    import numpy as np

    from cape.closedloop.provenance import run_models
    from cape.closedloop.setup import build_run
    from cape.config import check_eta, section
    from cape.controllers import controller_class
    from cape.io import atomic_folder, check_replaceable
    from cape.layout.names import check_name
    from cape.layout.record import write_run_files, write_timing
    from cape.layout.runs import RUN_FILES

    imported = time.perf_counter()
    config = _config(args)
    eta = check_eta(args.eta, "--eta")
    if args.seed < 0:
        raise CapeError(f"--seed {args.seed}: a seed is a non-negative integer")
    if args.replicate < 0:
        raise CapeError(f"--replicate {args.replicate}: a replicate is a non-negative integer")
    check_name(args.study, "--study")
    out = Path(args.out)
    check_replaceable(out, RUN_FILES, RUN_WHAT)  # before the lap, not after it
    folders = _model_folders(args)
    entries = section(config, "controllers")  # an unknown name: build_run says so
    needs = (
        args.controller in entries
        and controller_class(args.controller, entries[args.controller]).needs_internal_model
    )
    internal = (args.internal or args.plant) if needs else None
    used = run_models(config, args.plant, internal, folders, args.replicate)
    configured = time.perf_counter()
    run = build_run(
        config,
        args.plant,
        args.controller,
        eta,
        args.seed,
        args.internal,
        folders,
        args.raceline,
        validate=args.config_json is None,
        envelope_data=args.training_data,
    )
    built = time.perf_counter()
    result = run()
    lapped = time.perf_counter()
    metrics = {
        "study": args.study,
        "plant": args.plant,
        "controller": args.controller,
        "internal": run.internal,
        "eta": args.eta,
        "seed": args.seed,
        "replicate": args.replicate,
        "models": used,  # the trained networks it was computed with (cape.closedloop.provenance)
        **result.metrics,
    }
    ms = np.sort(result.solve_ms)
    timing: dict[str, Any] = {
        f"solve_ms_{name}": _percentile(ms, q) if ms.size else None
        for name, q in (("median", 50), ("p90", 90), ("p99", 99), ("max", 100))
    }
    # the run's three files appear together or not at all (one folder rename)
    with atomic_folder(out, RUN_FILES, RUN_WHAT) as folder:
        series_sha256 = write_run_files(folder, metrics, result.series)
        # the job's wall time by phase (s): start-up (the command's modules and arguments, from
        # the first of cape.cli's imports), the run's imports, reading the config, building the
        # run (models, solver), the lap (and in it the controller's and the plant's shares),
        # writing; what a process costs before and after these is what
        # benchmarks/rollout_job.py measures from outside
        lap = lapped - built
        timing["job_s"] = {
            "startup": round(imported - STARTED, 4),
            "config": round(configured - imported, 4),
            "build": round(built - configured, 4),
            "lap": round(lap, 4),
            "controller": round(float(np.sum(ms)) / 1e3, 4),
            "plant": round(result.plant_s, 4),
            "steps": int(metrics["steps"]),
            "write": round(time.perf_counter() - lapped, 4),
        }
        # the controller's steps by part (an NMPC's: benchmarks/draw_cost.py), and how many of
        # the SQP's failures its IPOPT rescue solved
        timing["controller_s"] = {k: round(v, 4) for k, v in sorted(result.controller_s.items())}
        timing["rescues"] = {
            "tried": int(metrics.get("rescues") or 0),
            "succeeded": result.rescues_succeeded,
        }
        write_timing(folder, timing, series_sha256)
    status = "lap" if metrics["success"] else f"failed ({metrics['failure']})"
    run_name = f"{args.plant}/{args.controller} η={args.eta} seed={args.seed}"
    print(f"{run_name}: {status}, lap time {metrics['lap_time']}")


def _plot_rollout_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--run", required=True, help="a run folder (metrics.json, timeseries.parquet)")
    _add_outputs(p, "--out", ".pdf or .png")
    p.add_argument("--raceline", help="reference .npz (default: results/raceline/<track>.npz)")
    _add_config_args(p)


@command(
    "plot-rollout",
    "figure of one run: path on the track and the five signals",
    _plot_rollout_arguments,
)
def cmd_plot_rollout(args: argparse.Namespace) -> None:
    from cape.closedloop.setup import load_reference
    from cape.layout.record import read_metrics, read_series
    from cape.plots.rollout import plot_rollout
    from cape.plots.style import save_figure

    config = _config(args)
    run = Path(args.run)
    metrics = read_metrics(run / "metrics.json")
    series = read_series(run)
    line, track = load_reference(config, args.raceline)
    outcome = (
        f"lap {metrics['lap_time']:.2f} s"
        if metrics["success"]
        else f"failed: {metrics['failure']}"
    )
    title = (
        f"plant {metrics['plant']}, controller {metrics['controller']} "
        f"(internal {metrics['internal']}), "
        f"η = {metrics['eta']}, seed {metrics['seed']}: {outcome}"
    )
    save_figure(plot_rollout(track, line.path.x, line.path.y, series, title), *args.out)
    print("wrote " + ", ".join(args.out))
