"""``cape build-solver``, ``rollout``, ``plot-rollout``: one closed-loop run and what it
needs (SPEC §5–§7).

Each command's arguments are defined right above it (``@command``)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from cape.cli.common import (
    DRAW,
    FIGURE_SUFFIXES,
    JSON_SUFFIXES,
    SEED,
    STARTED,
    _add_config_args,
    _add_model_folders,
    _add_outputs,
    _config,
    _files,
    _model_folders,
    claim,
    command,
)
from cape.layout import paths
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
    from cape.specs.run import RunSpec
    from cape.storage.io import write_text
    from cape.storage.ownership import Output

    spec = RunSpec.from_config(_config(args), args.controller)
    identity = f"{args.controller} with internal model {args.internal}"
    claim(args, Output(Path(args.out), "solver record", identity, JSON_SUFFIXES))
    run = build_run(
        spec,
        TRUTH,  # the plant does not enter the controller's NLP
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
    p.add_argument("--seed", required=True, type=SEED, help="seed of every random draw of the run")
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
        type=DRAW,
        help="the draw of the models given by --model (metrics.json's replicate; SPEC §4)",
    )
    _add_config_args(p)


@command("rollout", "one closed-loop lap: plant, controller, η, seed (SPEC §5)", _rollout_arguments)
def cmd_rollout(args: argparse.Namespace) -> None:
    from cape.closedloop.job import check_run, run_job
    from cape.layout.record import write_run_files, write_timing
    from cape.layout.runs import RUN_FILES, RunId
    from cape.specs.run import RunSpec
    from cape.storage.io import atomic_folder, check_replaceable

    imported = time.perf_counter()
    run = RunId(args.study, args.plant, args.internal or args.plant, args.controller, args.eta,
                args.seed, args.replicate)  # fmt: skip
    check_run(run)
    spec = RunSpec.from_config(_config(args), args.controller)
    out = Path(args.out)
    claim(args, _run_output(out, run, spec))  # before the lap, not after it
    check_replaceable(out, RUN_FILES, RUN_WHAT)
    record = run_job(
        spec,
        run,
        args.internal,
        _model_folders(args),
        args.raceline,
        validate=args.config_json is None and args.spec is None,
        envelope_data=args.training_data,
        started=STARTED,
        imported=imported,
    )
    # the run's three files appear together or not at all (one folder rename)
    with atomic_folder(out, RUN_FILES, RUN_WHAT) as folder:
        series_sha256 = write_run_files(folder, record.metrics, record.series)
        write_timing(folder, record.finish_timing(), series_sha256)
    metrics = record.metrics
    status = "lap" if metrics["success"] else f"failed ({metrics['failure']})"
    run_name = f"{args.plant}/{args.controller} η={args.eta} seed={args.seed}"
    print(f"{run_name}: {status}, lap time {metrics['lap_time']}")


def _run_output(out: Path, run: Any, spec: Any) -> Any:
    """A run folder as an output (``cape.storage.ownership``): the run ``run`` with the
    settings ``spec`` (its digest: the same run with other gains is another output)."""
    from cape.layout.runs import RUN_FILES
    from cape.specs import digest
    from cape.storage.ownership import Output

    identity = f"{'/'.join(run.parts())} [settings {digest(spec)[:16]}]"
    return Output(out, "run", identity, folder=True, files=tuple(RUN_FILES))


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
    from cape.specs.run import ReferenceSpec

    reference = ReferenceSpec.from_config(_config(args))
    claim(args, *_files(args.out, "figure of a run", FIGURE_SUFFIXES))
    run = Path(args.run)
    metrics = read_metrics(run / paths.METRICS)
    series = read_series(run)
    line, track = load_reference(reference, args.raceline)
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
