"""The ``cape`` command: the entry points the Snakemake rules call.

Each subcommand does one job of the workflow and writes its outputs atomically. Problems the
user can fix are reported as one clear message (exit status 2), never as a traceback.
"""

from __future__ import annotations

import time

STARTED = time.perf_counter()  # as the process starts: a rollout reports its own start-up

import argparse  # noqa: E402
import sys  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

from cape.errors import CapeError  # noqa: E402


def _add_config_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        metavar="FILE",
        help="YAML config to read (default: config/config.yaml)",
    )
    parser.add_argument(
        "--config-json",
        metavar="JSON",
        help="config sections as a JSON object (how the workflow passes them); overrides --config",
    )


def _add_tracks_dir(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--tracks-dir", help="folder of the verified track files (default: config tracks.dir)"
    )


def _add_outputs(parser: argparse.ArgumentParser, flag: str, what: str) -> None:
    """A repeatable output flag: one file per format (the suffix chooses it)."""
    parser.add_argument(
        flag, action="append", required=True, metavar="PATH", help=f"{what} (repeat)"
    )


def _add_models(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--model", action="append", required=True, metavar="NAME=DIR", help="trained model (repeat)"
    )


def _config(args: argparse.Namespace) -> dict[str, Any]:
    from cape.config import config_from_args

    return config_from_args(args.config, args.config_json)


# --- cape tracks ---------------------------------------------------------------------------
def cmd_tracks(args: argparse.Namespace) -> None:
    from cape.config import section
    from cape.tracks.fetch import obtain_tracks

    cfg = section(_config(args), "tracks")
    mirror = args.mirror if args.mirror is not None else cfg.get("mirror")
    dest = Path(args.dest or cfg["dir"])
    obtain_tracks(
        dest=dest,
        mirror=Path(mirror) if mirror else None,
        url_template=cfg["upstream_url"] if args.url is None else (args.url or None),
        timeout=float(cfg.get("download_timeout", 30)),
    )
    print(f"all track files verified in {dest}")


# --- cape data -----------------------------------------------------------------------------
def cmd_data(args: argparse.Namespace) -> None:
    from cape.config import section
    from cape.data.bayesrace import ProtocolSettings, generate_dataset
    from cape.io import save_npz
    from cape.tracks.track import load_raceline
    from cape.vehicle.params import GROUND_TRUTH

    config = _config(args)
    data_cfg = section(config, "data")
    if args.track not in data_cfg["tracks"]:
        raise CapeError(
            f"--track {args.track}: not a track of the config's `data.tracks` "
            f"({', '.join(sorted(data_cfg['tracks']))})"
        )
    tracks_dir = Path(args.tracks_dir or section(config, "tracks")["dir"])
    settings = ProtocolSettings.from_config(data_cfg, args.track)
    raceline = load_raceline(tracks_dir, data_cfg["tracks"][args.track]["raceline"])
    dataset = generate_dataset(raceline, GROUND_TRUTH, settings)
    save_npz(args.out, **dataset)
    print(f"wrote {args.out}: " + ", ".join(f"{k} {v.shape}" for k, v in dataset.items()))


# --- cape plot-tracks ----------------------------------------------------------------------
def cmd_plot_tracks(args: argparse.Namespace) -> None:
    import numpy as np

    from cape.config import section
    from cape.plots.style import save_figure
    from cape.plots.tracks import TrackPanel, plot_tracks
    from cape.tracks.track import load_raceline, load_track

    config = _config(args)
    catalogue = section(config, "tracks")["catalogue"]
    data_tracks = section(config, "data")["tracks"]
    tracks_dir = Path(args.tracks_dir or config["tracks"]["dir"])
    panels = []
    for item in args.data:
        name, sep, path = item.partition("=")
        if not sep or name not in catalogue or name not in data_tracks:
            raise CapeError(
                f"--data {item}: expected TRACK=PATH with TRACK one of {sorted(data_tracks)}"
            )
        entry = catalogue[name]
        with np.load(path) as npz:
            dataset = {k: npz[k] for k in npz.files}
        panels.append(
            TrackPanel(
                track=load_track(tracks_dir, name, entry["prefix"], entry["width"]),
                raceline=load_raceline(tracks_dir, data_tracks[name]["raceline"]),
                dataset=dataset,
            )
        )
    save_figure(plot_tracks(panels), *args.out)
    print("wrote " + ", ".join(args.out))


# --- cape raceline -------------------------------------------------------------------------
def cmd_raceline(args: argparse.Namespace) -> None:
    import numpy as np

    from cape.config import section
    from cape.integrity import sealed_arrays
    from cape.io import save_npz
    from cape.plots.style import save_figure
    from cape.plots.tracks import plot_raceline
    from cape.tracks.raceline import build_raceline, lap_time
    from cape.tracks.track import load_raceline, load_track
    from cape.vehicle.params import ACTUATOR_LIMITS, GROUND_TRUTH

    config = _config(args)
    settings = section(config, "reference")
    catalogue = section(config, "tracks")["catalogue"]
    if args.track not in catalogue:
        raise CapeError(
            f"--track {args.track}: not in `tracks.catalogue` ({', '.join(sorted(catalogue))})"
        )
    entry = catalogue[args.track]
    tracks_dir = Path(args.tracks_dir or config["tracks"]["dir"])
    track = load_track(tracks_dir, args.track, entry["prefix"], entry["width"])
    line = build_raceline(track, settings, GROUND_TRUTH, ACTUATOR_LIMITS)
    path = line.path
    scaled = np.clip(settings["scale"] * line.speed, settings["v_min"], settings["v_max"])
    ideal = float(np.sum(path.segment_lengths / scaled))
    save_npz(
        args.out,
        **sealed_arrays({
            "x": line.x,
            "y": line.y,
            "speed": line.speed,
            "s": path.s_points,
            "heading": path.heading(path.s_points),
            "curvature": path.curvature(path.s_points),
        }),
    )  # fmt: skip
    title = (
        f"{args.track}: CAPE raceline {path.length:.2f} m; ideal lap {lap_time(line):.2f} s at "
        f"v_path,\n{ideal:.2f} s at the reference speed (scale {settings['scale']}, "
        f"clipped to [{settings['v_min']}, {settings['v_max']}] m/s)"
    )
    print(title)
    if args.figure:
        bayesrace = load_raceline(tracks_dir, f"{entry['prefix']}_raceline.npz")
        save_figure(
            plot_raceline(track, line.x, line.y, line.speed, bayesrace, title), *args.figure
        )


# --- cape aggregate ------------------------------------------------------------------------
def cmd_aggregate(args: argparse.Namespace) -> None:
    from cape.io import atomic_open
    from cape.study.aggregate import collect_runs, summarise
    from cape.study.grid import RunId, canonical, study_runs

    config = _config(args)
    paths = [Path(p) for p in args.runs]
    if args.runs_from:
        paths += [Path(line) for line in Path(args.runs_from).read_text().split() if line]
    if paths:  # the runs named, each of the study its folder says
        pairs = [(RunId.parse(p).study, p) for p in paths]
    else:  # every run of the config's grid, read where it was computed
        internal = set(config["study"].get("internal_controllers", []))
        grid = canonical(study_runs(config["study"], config["disturbances"]["eta"],
                                    lambda c: c in internal))  # fmt: skip
        pairs = [(run.study, computed.folder(args.root) / "metrics.json")
                 for run, computed in grid.items()]  # fmt: skip
    runs = collect_runs(pairs, config["study"]["studies"])
    with atomic_open(args.out, "wb") as handle:
        runs.to_parquet(handle, index=False)
    summary = summarise(runs)
    with atomic_open(args.summary, "wb") as handle:
        summary.to_parquet(handle, index=False)
    ok = int(runs["success"].sum())
    print(f"{len(runs)} runs ({ok} laps, {len(runs) - ok} failures) → {args.out}; "
          f"{len(summary)} cells → {args.summary}")  # fmt: skip


# --- cape rollout --------------------------------------------------------------------------
PLANT_KINDS = "dpm|ddm|epm (learned), dpm-fixed|ddm-fixed|epm-fixed, or truth"


def cmd_rollout(args: argparse.Namespace) -> None:
    import json

    import numpy as np

    from cape.closedloop.setup import build_run
    from cape.config import check_eta
    from cape.io import atomic_folder, save_float_columns, write_text

    config = _config(args)
    eta = check_eta(args.eta, "--eta")
    if args.seed < 0:
        raise CapeError(f"--seed {args.seed}: a seed is a non-negative integer")
    started = time.perf_counter()
    run = build_run(
        config,
        args.plant,
        args.controller,
        eta,
        args.seed,
        args.internal,
        Path(args.models_dir),
        args.raceline,
        validate=args.config_json is None,
    )
    built = time.perf_counter()
    result = run()
    lapped = time.perf_counter()
    out = Path(args.out)
    metrics = {
        "study": args.study,
        "plant": args.plant,
        "controller": args.controller,
        "internal": run.internal,
        "eta": args.eta,
        "seed": args.seed,
        **result.metrics,
    }
    ms = result.solve_ms
    timing: dict[str, Any] = {
        f"solve_ms_{name}": float(np.percentile(ms, q)) if ms.size else None
        for name, q in (("median", 50), ("p90", 90), ("p99", 99), ("max", 100))
    }
    # the run's three files appear together or not at all (one folder rename)
    with atomic_folder(out) as folder:
        save_float_columns(folder / "timeseries.parquet", result.series)
        write_text(folder / "metrics.json", json.dumps(metrics, indent=2, sort_keys=True) + "\n")
        # the job's wall time by phase (s): start-up (interpreter, imports, arguments), building
        # the run (models, solver), the lap, writing
        timing["job_s"] = {
            "startup": round(started - STARTED, 4),
            "build": round(built - started, 4),
            "lap": round(lapped - built, 4),
            "steps": int(metrics["steps"]),
            "write": round(time.perf_counter() - lapped, 4),
        }
        write_text(folder / "timing.json", json.dumps(timing, indent=2, sort_keys=True) + "\n")
    status = "lap" if metrics["success"] else f"failed ({metrics['failure']})"
    run_name = f"{args.plant}/{args.controller} η={args.eta} seed={args.seed}"
    print(f"{run_name}: {status}, lap time {metrics['lap_time']}")


def cmd_build_solver(args: argparse.Namespace) -> None:
    import json

    from cape.closedloop.setup import build_run
    from cape.io import write_text

    config = _config(args)
    run = build_run(
        config,
        "truth",  # the plant does not enter the controller's NLP
        args.controller,
        0.0,
        0,
        args.internal,
        Path(args.models_dir),
        args.raceline,
    )
    controller = run.controller
    libraries = [
        str(solver.library)
        for solver in (getattr(controller, "backend", None), getattr(controller, "rescue", None))
        if solver is not None and solver.library is not None
    ]
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


def cmd_plot_rollout(args: argparse.Namespace) -> None:
    import json

    import pandas as pd

    from cape.closedloop.setup import load_reference
    from cape.plots.rollout import plot_rollout
    from cape.plots.style import save_figure

    config = _config(args)
    run = Path(args.run)
    metrics_path = run / "metrics.json"
    if not metrics_path.is_file():
        raise CapeError(f"{metrics_path}: missing; run `snakemake --cores 1 {metrics_path}` first")
    metrics = json.loads(metrics_path.read_text())
    series = pd.read_parquet(run / "timeseries.parquet")
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


# --- cape train ----------------------------------------------------------------------------
def _model_spec(config: dict[str, Any], name: str) -> dict[str, Any]:
    from cape.config import section

    models = section(config, "models")
    if name not in models:
        raise CapeError(
            f"--model {name}: not in the config's `models` ({', '.join(sorted(models))})"
        )
    return models[name]


def cmd_train(args: argparse.Namespace) -> None:
    import hashlib

    import numpy as np
    import torch

    from cape.config import section
    from cape.io import write_text
    from cape.models.checkpoint import save_model
    from cape.models.training import TrainingData, train_model

    config = _config(args)
    spec = _model_spec(config, args.model)
    data_cfg, train_cfg = section(config, "data"), section(config, "training")
    seed = int(args.seed if args.seed is not None else train_cfg["seed"])
    data_path = Path(args.data)
    if not data_path.is_file():
        raise CapeError(
            f"--data {data_path}: not found; build it with `snakemake --cores 2 {data_path}`"
        )
    with np.load(data_path) as npz:
        dataset = {k: npz[k] for k in npz.files}
    split = data_cfg["split"]
    data = TrainingData.from_dataset(
        dataset, int(spec["history"]), float(split["train_fraction"]), int(split["seed"])
    )
    threads = int(args.threads or train_cfg["threads"])
    print(
        f"training {args.model}: {len(data.train)} training / {len(data.val)} validation "
        f"windows, seed {seed}"
    )
    result = train_model(
        args.model,
        spec,
        data,
        ts=float(data_cfg["ts"]),
        seed=seed,
        epochs=args.epochs,
        threads=threads,
        fused=bool(train_cfg.get("fused_adam", True)),
    )
    out = Path(args.out)
    meta = {
        "seed": seed,
        "epochs": len(result.losses),
        "best_epoch": result.best_epoch,
        "best_val_loss": result.best_val_loss,
        "wall_seconds": result.wall_seconds,
        "threads": threads,
        "split": split,
        "scaler": data.scaler.to_dict(),
        "data_file": str(data_path),
        "data_sha256": hashlib.sha256(data_path.read_bytes()).hexdigest(),
        "torch_version": torch.__version__,
    }
    save_model(result.model, out, meta)
    rows = ["epoch,train_loss,val_loss"] + [
        f"{r['epoch']},{r['train_loss']:.17g},{r['val_loss']:.17g}" for r in result.losses
    ]
    write_text(out / "loss.csv", "\n".join(rows) + "\n")
    print(
        f"{args.model}: best validation MSE {result.best_val_loss:.4e} "
        f"at epoch {result.best_epoch} "
        f"of {len(result.losses)}; {result.wall_seconds:.1f} s; saved to {out}"
    )


# --- model evaluation ------------------------------------------------------------------------
def _load_npz(path: str) -> dict[str, Any]:
    import numpy as np

    if not Path(path).is_file():
        raise CapeError(f"{path}: not found; build it with `snakemake --cores 2 {path}`")
    with np.load(path) as npz:
        return {k: npz[k] for k in npz.files}


def _load_models(items: list[str]) -> dict[str, Any]:
    """``NAME=DIR`` pairs → trained models, in the order given."""
    from cape.models.checkpoint import load_model

    models = {}
    for item in items:
        name, sep, folder = item.partition("=")
        if not sep:
            raise CapeError(f"--model {item}: expected NAME=FOLDER, e.g. epm=results/models/epm")
        models[name] = load_model(folder, expected_name=name)
    return models


def cmd_freeze(args: argparse.Namespace) -> None:
    import json

    from cape.config import section
    from cape.integrity import sealed_record
    from cape.io import write_text
    from cape.models.evaluate import frozen_parameters
    from cape.models.training import TrainingData

    config = _config(args)
    split = section(config, "data")["split"]
    ((name, model),) = _load_models([args.model]).items()
    data = TrainingData.from_dataset(
        _load_npz(args.data), model.history, float(split["train_fraction"]), int(split["seed"])
    )
    frozen = frozen_parameters(model, data.train)
    payload = sealed_record({
        "model": name,
        "source": "median of Φ over the ETHZ training windows (SPEC §4.5)",
        "phi": frozen,
    })  # fmt: skip
    write_text(args.out, json.dumps(payload, indent=2) + "\n")
    print(f"wrote {args.out}: " + ", ".join(f"{k}={v:.4g}" for k, v in frozen.items()))


def cmd_export_network(args: argparse.Namespace) -> None:
    from cape.models.checkpoint import export_network

    name, sep, folder = args.model.partition("=")
    if not sep:
        raise CapeError(f"--model {args.model}: expected NAME=FOLDER, e.g. epm=results/models/epm")
    out = export_network(folder, args.out, expected_name=name)
    print(f"wrote {out}: the {name} network for the NumPy closed loop")
    compile_settings = _config(args).get("rollout", {}).get("compile")
    if compile_settings and compile_settings.get("enabled", False):
        import numpy as np

        from cape.models.network import load_network

        network = load_network(out, compile_settings)
        network.phi(np.zeros((network.history, 7)))  # builds and caches the compiled GRU
        print("compiled its GRU into the cache " + str(compile_settings.get("cache")))


def cmd_openloop(args: argparse.Namespace) -> None:
    import numpy as np

    from cape.config import section
    from cape.models.evaluate import rear_slip
    from cape.models.report import openloop_table
    from cape.tables import write_table

    config = _config(args)
    horizon = int(section(config, "training").get("multistep_horizon", 15))
    train, test = _load_npz(args.train_data), _load_npz(args.test_data)
    table = openloop_table(
        _load_models(args.model), train, test, section(config, "data")["split"], horizon
    )
    slip_train, slip_test = rear_slip(train), rear_slip(test)
    caption = (
        "Open-loop error of the learned models: one-step RMSE on the ETHZ validation split and on "
        f"ETHZMobil, mean absolute error after {horizon} open-loop steps on ETHZMobil, and the "
        "paper's one-step RMSE (vx, vy in m/s, ω in rad/s). ETHZMobil is an extrapolation: its "
        f"rear slip angle reaches {slip_test.max():.2f} rad (99th percentile "
        f"{np.percentile(slip_test, 99):.2f}) against {np.percentile(slip_train, 99):.2f} rad "
        "(99th percentile) in the ETHZ training data, so a model whose rear tyre is right only "
        "within ETHZ's range errs there (docs/models.md). ETHZMobil ω RMSE over the paper's: "
        + ", ".join(
            f"{row['model'].upper()} {row['test_rmse_omega'] / row['paper_rmse_omega']:.2g}×"
            for _, row in table.iterrows()
            if np.isfinite(row["paper_rmse_omega"])
        )
        + "."
    )
    write_table(
        table, args.out, formats={c: ".3e" for c in table.columns if c != "model"}, caption=caption
    )
    print(table.to_string(index=False))


def cmd_complexity(args: argparse.Namespace) -> None:
    import torch

    from cape.config import section
    from cape.data.windows import make_windows
    from cape.models.report import complexity_table
    from cape.tables import write_table

    config = _config(args)
    torch.set_num_threads(1)
    models = _load_models(args.model)
    data = _load_npz(args.data)
    windows = {name: make_windows(data, m.history).features[100] for name, m in models.items()}
    repeats = int(section(config, "training").get("inference_repeats", 2000))
    table = complexity_table(models, windows, repeats)
    formats = {"params_M": ".4f", "size_MB": ".2f", "flops_M": ".3f", "inference_ms": ".3f"}
    formats.update({f"paper_{k}": v for k, v in formats.items()})
    caption = (
        "Model complexity and inference efficiency: parameters (millions), float32 size (MiB), "
        "layers, FLOPs per prediction (millions, counted by PyTorch's flop counter) and the "
        "median time of one single-window Φ prediction on the fast path (ms, this CPU, 1 thread)."
    )
    write_table(table, args.out, formats=formats, caption=caption)
    print(table.to_string(index=False))


def _colors_labels(
    config: dict[str, Any], names: list[str]
) -> tuple[dict[str, str], dict[str, str]]:
    from cape.config import section

    models = section(config, "models")
    colors = {n: models.get(n, {}).get("color", f"C{i}") for i, n in enumerate(names)}
    labels = {n: models.get(n, {}).get("label", n.upper()) for n in names}
    return colors, labels


def cmd_plot_models(args: argparse.Namespace) -> None:
    import numpy as np
    import pandas as pd

    from cape.config import section
    from cape.data.windows import make_windows
    from cape.models.evaluate import predict_phi
    from cape.models.trained import read_meta
    from cape.plots.models import plot_phi, plot_training_curves
    from cape.plots.style import save_figure
    from cape.vehicle.dynamics import drivetrain_force
    from cape.vehicle.params import GROUND_TRUTH

    config = _config(args)
    ts = float(section(config, "data")["ts"])
    models = _load_models(args.model)
    colors, labels = _colors_labels(config, list(models))
    data = _load_npz(args.data)
    phis, time = {}, None
    for name, model in models.items():
        windows = make_windows(data, model.history)
        phis[name] = (list(model.param_names), predict_phi(model, windows.features))
    # align on the common time axis: the label step of each window
    shortest = min(len(phi) for _, phi in phis.values())
    aligned = {n: (pn, phi[-shortest:]) for n, (pn, phi) in phis.items()}
    time = data["time"][-shortest:]
    steps = np.arange(data["inputs"].shape[1])[-shortest - 1 : -1]
    true_frx = drivetrain_force(
        data["dstates"][3, steps], data["inputs"][0, steps], GROUND_TRUTH.as_dict()
    )
    save_figure(plot_phi(aligned, time, colors, labels, ts, true_frx), *args.phi_out)
    losses = {}
    best = {}
    for item in args.model:
        name, _, folder = item.partition("=")
        losses[name] = pd.read_csv(Path(folder) / "loss.csv")
        best[name] = int(read_meta(folder)["best_epoch"])
    save_figure(plot_training_curves(losses, best, colors, labels), *args.curves_out)
    print("wrote " + ", ".join([*args.phi_out, *args.curves_out]))


def build_parser() -> argparse.ArgumentParser:
    from cape import __version__

    parser = argparse.ArgumentParser(
        prog="cape",
        description="CAPE: control algorithm performance evaluation under learned vehicle "
        "dynamics models. Subcommands are the steps of the Snakemake workflow.",
    )
    parser.add_argument("--version", action="version", version=f"cape {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("tracks", help="obtain and verify the BayesRace track files (SPEC §2)")
    p.add_argument("--dest", help="destination folder (default: config tracks.dir)")
    p.add_argument(
        "--mirror", help="local folder holding the files (default: config tracks.mirror)"
    )
    p.add_argument("--url", help="URL template with {commit} and {file}; '' disables download")
    _add_config_args(p)
    p.set_defaults(func=cmd_tracks)

    p = sub.add_parser(
        "data", help="generate a DYN-PP data set by the BayesRace protocol (SPEC §3)"
    )
    p.add_argument("--track", required=True, help="track name, e.g. ETHZ or ETHZMobil")
    p.add_argument("--out", required=True, help="output .npz path")
    _add_tracks_dir(p)
    _add_config_args(p)
    p.set_defaults(func=cmd_data)

    p = sub.add_parser("plot-tracks", help="figure of the tracks, racelines and generated data")
    p.add_argument(
        "--data",
        action="append",
        required=True,
        metavar="TRACK=PATH",
        help="a data set to draw (repeat)",
    )
    _add_outputs(p, "--out", "output file, .pdf or .png")
    _add_tracks_dir(p)
    _add_config_args(p)
    p.set_defaults(func=cmd_plot_tracks)

    p = sub.add_parser("raceline", help="CAPE's minimum-curvature reference raceline (SPEC §2)")
    p.add_argument("--track", required=True, help="track name from `tracks.catalogue`")
    p.add_argument("--out", required=True, help="output .npz (x, y, speed, s, heading, curvature)")
    p.add_argument(
        "--figure", action="append", metavar="PATH", help="figure beside BayesRace's (repeat)"
    )
    _add_tracks_dir(p)
    _add_config_args(p)
    p.set_defaults(func=cmd_raceline)

    p = sub.add_parser("rollout", help="one closed-loop lap: plant, controller, η, seed (SPEC §5)")
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
    p.add_argument("--models-dir", default="results/models", help="folder of the trained models")
    p.add_argument("--raceline", help="reference .npz (default: results/raceline/<track>.npz)")
    p.add_argument("--study", default="adhoc", help="the study the run belongs to (metrics.json)")
    _add_config_args(p)
    p.set_defaults(func=cmd_rollout)

    p = sub.add_parser(
        "build-solver",
        help="build a controller's NLP for an internal model once, compiling it into the cache",
    )
    p.add_argument("--controller", required=True, help="controller name from the config (nmpc…)")
    p.add_argument("--internal", required=True, help=PLANT_KINDS)
    p.add_argument("--out", required=True, help="record of the compiled library (.json)")
    p.add_argument("--models-dir", default="results/models", help="folder of the trained models")
    p.add_argument("--raceline", help="reference .npz (default: results/raceline/<track>.npz)")
    _add_config_args(p)
    p.set_defaults(func=cmd_build_solver)

    p = sub.add_parser(
        "aggregate", help="every run's metrics in one table, and per-cell means with 95%% CIs"
    )
    p.add_argument("runs", nargs="*", help="metrics.json files of the runs (default: the grid)")
    p.add_argument("--runs-from", metavar="FILE", help="a file listing metrics.json paths")
    p.add_argument("--root", default="results/runs", help="where the grid's runs are")
    p.add_argument("--out", required=True, help="the tidy table of runs (.parquet)")
    p.add_argument("--summary", required=True, help="the per-cell summary (.parquet)")
    _add_config_args(p)
    p.set_defaults(func=cmd_aggregate)

    p = sub.add_parser(
        "plot-rollout", help="figure of one run: path on the track and the five signals"
    )
    p.add_argument("--run", required=True, help="a run folder (metrics.json, timeseries.parquet)")
    _add_outputs(p, "--out", ".pdf or .png")
    p.add_argument("--raceline", help="reference .npz (default: results/raceline/<track>.npz)")
    _add_config_args(p)
    p.set_defaults(func=cmd_plot_rollout)

    p = sub.add_parser("train", help="train a learned model on the ETHZ windows (SPEC §4)")
    p.add_argument(
        "--model", required=True, help="model name from the config's `models` (dpm, ddm, epm, ...)"
    )
    p.add_argument("--data", required=True, help="training data set (.npz)")
    p.add_argument("--out", required=True, help="output folder for model.pt, meta.json, loss.csv")
    p.add_argument("--epochs", type=int, help="override the config's epoch count (smoke runs)")
    p.add_argument("--seed", type=int, help="override training.seed")
    p.add_argument("--threads", type=int, help="override training.threads")
    _add_config_args(p)
    p.set_defaults(func=cmd_train)

    p = sub.add_parser(
        "freeze",
        help="median Φ over the training windows, for the fixed-parameter plants (SPEC §4.5)",
    )
    p.add_argument("--model", required=True, metavar="NAME=DIR", help="trained model")
    p.add_argument("--data", required=True, help="training data set (.npz)")
    p.add_argument("--out", required=True, help="output .json")
    _add_config_args(p)
    p.set_defaults(func=cmd_freeze)

    p = sub.add_parser(
        "export-network",
        help="export a trained network to network.npz, which the closed loop runs without PyTorch",
    )
    p.add_argument("--model", required=True, metavar="NAME=DIR", help="trained model")
    p.add_argument("--out", help="output .npz (default: DIR/network.npz)")
    _add_config_args(p)
    p.set_defaults(func=cmd_export_network)

    p = sub.add_parser("openloop", help="open-loop error table of trained models (SPEC §4.4)")
    _add_models(p)
    p.add_argument(
        "--train-data", required=True, help="ETHZ data set (.npz), for its validation split"
    )
    p.add_argument("--test-data", required=True, help="ETHZMobil data set (.npz)")
    _add_outputs(p, "--out", ".csv, .md or .tex")
    _add_config_args(p)
    p.set_defaults(func=cmd_openloop)

    p = sub.add_parser("complexity", help="model complexity and inference time table (SPEC §4.4)")
    _add_models(p)
    p.add_argument("--data", required=True, help="data set whose windows are timed (.npz)")
    _add_outputs(p, "--out", ".csv, .md or .tex")
    _add_config_args(p)
    p.set_defaults(func=cmd_complexity)

    p = sub.add_parser(
        "plot-models", help="figures of predicted Φ against the truth, and of training"
    )
    _add_models(p)
    p.add_argument("--data", required=True, help="ETHZMobil data set (.npz)")
    _add_outputs(p, "--phi-out", "Φ figure, .pdf or .png")
    _add_outputs(p, "--curves-out", "training curves, .pdf or .png")
    _add_config_args(p)
    p.set_defaults(func=cmd_plot_models)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one subcommand; a ``CapeError`` becomes a one-line message and exit status 2."""
    args = build_parser().parse_args(argv)
    func: Callable[[argparse.Namespace], None] = args.func
    try:
        func(args)
    except CapeError as exc:
        print(f"cape {args.command}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
