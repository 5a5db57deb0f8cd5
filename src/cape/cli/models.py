"""``cape train``, ``freeze``, ``export-network``, ``openloop``, ``complexity``,
``plot-models``: the learned models and their tables and figures (SPEC §4).

Each command's arguments are defined right above it (``@command``)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from cape.cli.common import (
    DRAW,
    FIGURE_SUFFIXES,
    JSON_SUFFIXES,
    PROVENANCE_COLUMNS,
    TABLE_SUFFIXES,
    _add_config_args,
    _add_models,
    _add_outputs,
    _config,
    _files,
    _load_models,
    _made_from,
    _read_dataset,
    _with_provenance,
    bounded,
    claim,
    command,
    model_made,
)
from cape.config import schema_default
from cape.errors import CapeError
from cape.layout import paths


def _spec(args: argparse.Namespace) -> Any:
    """The model commands' settings (``cape.specs.models.ModelsSpec``)."""
    from cape.specs.models import ModelsSpec

    return ModelsSpec.from_config(_config(args))


def _train_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--model", required=True, help="model name from the config's `models` (dpm, ddm, epm, ...)"
    )
    p.add_argument("--data", required=True, help="training data set (.npz)")
    p.add_argument("--out", required=True, help="output folder for model.pt, meta.json, loss.csv")
    p.add_argument(
        "--epochs",
        type=bounded("models.*.train.epochs"),
        help="override the config's epoch count (smoke runs)",
    )
    p.add_argument("--seed", type=bounded("training.seed"), help="override training.seed")
    p.add_argument(
        "--replicate",
        type=DRAW,
        help="the draw this training is (SPEC §4; meta.json: a run refuses another's); the "
        "workflow's trainings have none: `cape draw` makes a draw of one",
    )
    p.add_argument("--threads", type=bounded("training.threads"), help="override training.threads")
    p.add_argument(
        "--checkpoint-every",
        type=bounded("training.checkpoint_every"),
        metavar="SECONDS",
        help="write the resumable checkpoint at most this often (default: "
        f"training.checkpoint_every, else {schema_default('training.checkpoint_every')}; 0: "
        "after every epoch)",
    )
    _add_config_args(p)


@command("train", "train a learned model on the ETHZ windows (SPEC §4)", _train_arguments)
def cmd_train(args: argparse.Namespace) -> None:
    from cape.specs.training import TrainingSpec
    from cape.training.kernels import pin_before_torch, pin_inductor

    spec = TrainingSpec.from_config(_config(args), args.model)
    pin_before_torch(spec.kernels)  # MKL's and ATen's code paths are read when PyTorch loads
    pin_inductor(spec.kernels)
    from cape.storage.integrity import file_digest
    from cape.training.checkpoint import save_model
    from cape.training.run import planned_identity, run_training

    out = Path(args.out)  # --epochs, --threads, ... were checked (common.check_bounds)
    try:
        data_sha256 = file_digest(args.data)
    except OSError:  # reading it below says what is wrong, after the claim
        data_sha256 = None
    training = planned_identity(spec, data_sha256 or "unreadable", args.seed, args.epochs,
                                args.threads)  # fmt: skip
    as_draw = "" if args.replicate is None else f" as draw {args.replicate}"
    claim(args, _training_output(out, training + as_draw))  # before reading, before training
    dataset = _read_dataset(args.data)
    run = run_training(spec, dataset, Path(args.data), out, seed=args.seed, epochs=args.epochs,
                       threads=args.threads, replicate=args.replicate,
                       checkpoint_every=args.checkpoint_every, data_sha256=data_sha256)  # fmt: skip
    result = run.result
    if result.rewritten or result.resumed_from:
        print(_resumed(run))
    # the checkpoint of the last epoch stays: a rerun after a crash (Snakemake deletes the
    # outputs of a job it had not recorded as finished) rewrites them from it in seconds
    save_model(run.model, out, run.meta, {paths.LOSSES: run.losses_csv.encode()})
    print(
        f"{args.model}: best validation MSE {result.best_val_loss:.4e} "
        f"at epoch {result.best_epoch} "
        f"of {len(result.losses)}; {result.wall_seconds:.1f} s; saved to {out}"
    )


def _resumed(run: Any) -> str:
    """How a training that did not start afresh went on: rewritten, or resumed."""
    if run.result.rewritten:
        return (f"already trained: its outputs rewritten from {run.checkpoint} (epoch "
                f"{len(run.result.losses)})")  # fmt: skip
    return f"resumed from {run.checkpoint} after epoch {run.result.resumed_from}"


def _training_output(out: Path, identity: str) -> Any:
    """A training's folder as an output (``cape.storage.ownership``): its identity is its
    model, seed and recipe digest (``cape.training.run.training_identity``)."""
    from cape.storage.ownership import Output

    files = (paths.WEIGHTS, paths.META, paths.LOSSES)
    return Output(out, "trained model", identity, folder=True, files=files)


def _draw_output(out: Path, model: str, replicate: int, draw: Any, cap: int) -> Any:
    """A draw's folder as an output: draw ``replicate`` of ``model``, made from the trainings
    it consulted (their seeds and the chosen one's weights) under its cap."""
    from cape.storage.ownership import Output

    choice = draw.choice
    seeds = ", ".join(str(o.seed) for o in choice.consulted)
    chosen = choice.consulted[choice.index].weights_sha256[:16]
    identity = (f"{_model_identity(model, replicate)} [seeds {seeds}, cap "
                f"{cap}, weights {chosen}]")  # fmt: skip
    files = (paths.WEIGHTS, paths.META, paths.LOSSES)
    return Output(out, "trained model", identity, folder=True, files=files)


def _model_identity(model: str, replicate: int | None) -> str:
    return model if replicate is None else f"{model} of replicate {replicate}"


def _made_from_weights(item: str) -> str:
    """The identity of an output made from one trained model ``NAME=DIR`` (its health record,
    frozen Φ, exported network): the model, its draw and its weights digest."""
    made = model_made(item)
    if made is None:
        return item.partition("=")[0]  # loading the model says what --model takes
    name, replicate, weights = made
    return f"{_model_identity(name, replicate)} [{weights[:16]}]"


def _check_training_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", required=True, metavar="NAME=DIR", help="a trained model's folder")
    p.add_argument(
        "--data", required=True, help="training data set (.npz), for its validation split"
    )
    p.add_argument("--out", required=True, help="the health record (.json)")
    _add_config_args(p)


@command(
    "check-training",
    "did a training work? the checks on the training alone (SPEC §4): its health.json",
    _check_training_arguments,
)
def cmd_check_training(args: argparse.Namespace) -> None:
    import json

    from cape.models.trained import read_meta
    from cape.storage.io import write_text
    from cape.storage.ownership import Output
    from cape.training.draws import train_loss
    from cape.training.evaluate import one_step_rmse
    from cape.training.health import training_outcome
    from cape.training.loop import TrainingData

    settings = _spec(args)
    claim(args, Output(Path(args.out), "health record", _made_from_weights(args.model),
                        JSON_SUFFIXES))  # fmt: skip
    ((name, model),) = _load_models([args.model]).items()
    folder = Path(args.model.partition("=")[2])
    meta = read_meta(folder)
    split = settings.split
    data = TrainingData.from_dataset(
        _read_dataset(args.data), model.history, float(split.train_fraction), int(split.seed)
    )
    outcome = training_outcome(
        name,
        int(meta["seed"]),
        one_step_rmse(model, data.val),
        train_loss(folder),  # as `cape draw` reads it again, to check the verdict
        settings.health,
        str(meta["weights_sha256"]),
    )
    write_text(args.out, json.dumps(outcome.to_dict(), indent=2, sort_keys=True) + "\n")
    said = "trained" if outcome.trained else "failed: " + "; ".join(outcome.reasons)
    print(f"{name} seed {outcome.seed}: {said}")


def _draw_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", required=True, help="model name from the config's `models`")
    p.add_argument("--replicate", required=True, type=DRAW, help="the draw (0, 1, …)")
    p.add_argument(
        "--training",
        action="append",
        required=True,
        metavar="DIR",
        help="the model's trainings in seed order, each with its health.json (repeat; each "
        "once, seeds strictly increasing)",
    )
    p.add_argument(
        "--max-trainings",
        required=True,
        type=bounded("training.max_trainings"),
        help="training.max_trainings (the cap)",
    )
    p.add_argument("--out", required=True, help="the draw's model folder")
    _add_config_args(p)  # training.health: each consulted record's verdict is checked again


@command(
    "draw",
    "make draw r of a model from its (r + 1)-th training that works (SPEC §4)",
    _draw_arguments,
)
def cmd_draw(args: argparse.Namespace) -> None:
    from cape.storage.io import write_files
    from cape.training.draws import make_draw

    out = Path(args.out)  # --replicate and --max-trainings were checked (common.check_bounds)
    settings = _spec(args).health
    # every refusal of the trainings given (twice, out of seed order, a record that does not
    # check out) before anything is written, the output's claim included
    draw = make_draw(
        args.model, args.replicate, args.max_trainings, [Path(t) for t in args.training], settings
    )
    claim(args, _draw_output(out, args.model, args.replicate, draw, args.max_trainings))
    write_files({out / name: content for name, content in draw.files.items()})
    choice = draw.choice
    said = "trained" if choice.trained else "failed (the cap was reached)"
    print(
        f"{args.model} draw {args.replicate}: training {choice.index} "
        f"(seed {choice.consulted[choice.index].seed}), {said}; "
        f"{len(choice.consulted)} trainings consulted"
    )


def _freeze_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", required=True, metavar="NAME=DIR", help="trained model")
    p.add_argument("--data", required=True, help="training data set (.npz)")
    p.add_argument("--out", required=True, help="output .json")
    _add_config_args(p)


@command(
    "freeze",
    "median Φ over the training windows, for the fixed-parameter plants (SPEC §4.5)",
    _freeze_arguments,
)
def cmd_freeze(args: argparse.Namespace) -> None:
    import json

    from cape.models.trained import read_meta
    from cape.storage.integrity import sealed_record
    from cape.storage.io import write_text
    from cape.storage.ownership import Output
    from cape.training.evaluate import frozen_parameters
    from cape.training.loop import TrainingData

    split = _spec(args).split
    claim(args, Output(Path(args.out), "frozen parameters", _made_from_weights(args.model),
                        JSON_SUFFIXES))  # fmt: skip
    ((name, model),) = _load_models([args.model]).items()
    data = TrainingData.from_dataset(
        _read_dataset(args.data), model.history, float(split.train_fraction), int(split.seed)
    )
    frozen = frozen_parameters(model, data.train)
    folder = args.model.partition("=")[2]
    payload = sealed_record({
        "model": name,
        "source": "median of Φ over the ETHZ training windows (SPEC §4.5)",
        "phi": frozen,
        "weights_sha256": read_meta(folder)["weights_sha256"],  # the weights it is from
    })  # fmt: skip
    write_text(args.out, json.dumps(payload, indent=2) + "\n")
    print(f"wrote {args.out}: " + ", ".join(f"{k}={v:.4g}" for k, v in frozen.items()))


def _export_network_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", required=True, metavar="NAME=DIR", help="trained model")
    p.add_argument("--out", help="output .npz (default: DIR/network.npz)")
    _add_config_args(p)


@command(
    "export-network",
    "export a trained network to network.npz, which the closed loop runs without PyTorch",
    _export_network_arguments,
)
def cmd_export_network(args: argparse.Namespace) -> None:
    from cape.training.checkpoint import export_network

    name, sep, folder = args.model.partition("=")
    if not sep:
        raise CapeError(
            f"--model {args.model}: expected NAME=FOLDER, e.g. epm={paths.model_dir('epm')}"
        )
    from cape.storage.ownership import Output

    compile_settings = _spec(args).rollout_compile  # a bad --spec: refused before any work
    target = Path(args.out) if args.out else Path(folder) / paths.NETWORK
    claim(args, Output(target, "network", _made_from_weights(args.model), (".npz",)))
    out = export_network(folder, target, expected_name=name)
    print(f"wrote {out}: the {name} network for the closed loop")
    if compile_settings is not None and compile_settings.enabled:
        import numpy as np

        from cape.models.network import load_network

        network = load_network(out, compile_settings.as_settings())
        network.phi(np.zeros((network.history, 7)))  # builds and caches the compiled Φ
        if network.library is not None:
            print(f"compiled its Φ (GRU, trunk and guard) into {network.library}")


def _openloop_arguments(p: argparse.ArgumentParser) -> None:
    _add_models(p)
    p.add_argument(
        "--train-data", required=True, help="ETHZ data set (.npz), for its validation split"
    )
    p.add_argument("--test-data", required=True, help="ETHZMobil data set (.npz)")
    _add_outputs(p, "--out", ".csv, .md or .tex")
    _add_config_args(p)


@command("openloop", "open-loop error table of trained models (SPEC §4.4)", _openloop_arguments)
def cmd_openloop(args: argparse.Namespace) -> None:
    import numpy as np
    import torch

    from cape.storage.tables import write_table
    from cape.training.evaluate import rear_slip
    from cape.training.model_tables import openloop_table

    settings = _spec(args)
    made = _made_from(args.model, [args.train_data, args.test_data], settings)
    claim(args, *_files(args.out, "open-loop error table", TABLE_SUFFIXES, identity=made))
    torch.set_num_threads(1)  # the same numbers on any machine, by hand as in the workflow
    horizon = settings.multistep_horizon
    train, test = _read_dataset(args.train_data), _read_dataset(args.test_data)
    table = openloop_table(_load_models(args.model), train, test, settings.split, horizon)
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
    formats = {c: ".3e" for c in table.columns if c != "model"}
    table = _with_provenance(table, args.model)
    write_table(table, args.out, formats=formats, caption=caption, csv_only=PROVENANCE_COLUMNS)
    print(table.drop(columns=list(PROVENANCE_COLUMNS)).to_string(index=False))


def _complexity_arguments(p: argparse.ArgumentParser) -> None:
    _add_models(p)
    p.add_argument("--data", required=True, help="data set whose windows are timed (.npz)")
    _add_outputs(p, "--out", ".csv, .md or .tex")
    _add_config_args(p)


@command(
    "complexity", "model complexity and inference time table (SPEC §4.4)", _complexity_arguments
)
def cmd_complexity(args: argparse.Namespace) -> None:
    import torch

    from cape.data.windows import make_windows
    from cape.storage.tables import write_table
    from cape.training.model_tables import complexity_table

    settings = _spec(args)
    made = _made_from(args.model, [args.data], settings)
    claim(args, *_files(args.out, "complexity table", TABLE_SUFFIXES, identity=made))
    torch.set_num_threads(1)
    models = _load_models(args.model)
    data = _read_dataset(args.data)
    windows = {name: make_windows(data, m.history).features[100] for name, m in models.items()}
    repeats = settings.inference_repeats
    table = complexity_table(models, windows, repeats)
    formats = {"params_M": ".4f", "size_MB": ".2f", "flops_M": ".3f", "inference_ms": ".3f"}
    formats.update({f"paper_{k}": v for k, v in formats.items()})
    caption = (
        "Model complexity and inference efficiency: parameters (millions), float32 size (MiB), "
        "layers, FLOPs per prediction (millions, counted by PyTorch's flop counter) and the "
        "median time of one single-window Φ prediction on the fast path (ms, this CPU, 1 thread)."
    )
    table = _with_provenance(table, args.model)
    write_table(table, args.out, formats=formats, caption=caption, csv_only=PROVENANCE_COLUMNS)
    print(table.drop(columns=list(PROVENANCE_COLUMNS)).to_string(index=False))


def _plot_models_arguments(p: argparse.ArgumentParser) -> None:
    _add_models(p)
    p.add_argument("--data", required=True, help="ETHZMobil data set (.npz)")
    _add_outputs(p, "--phi-out", "Φ figure, .pdf or .png")
    _add_outputs(p, "--curves-out", "training curves, .pdf or .png")
    _add_config_args(p)


@command(
    "plot-models",
    "figures of predicted Φ against the truth, and of training",
    _plot_models_arguments,
)
def cmd_plot_models(args: argparse.Namespace) -> None:
    import numpy as np

    from cape.data.windows import make_windows
    from cape.models.trained import read_training
    from cape.plots.models import plot_phi, plot_training_curves
    from cape.plots.style import save_figure
    from cape.training.evaluate import predict_phi
    from cape.vehicle.dynamics import drivetrain_force
    from cape.vehicle.params import GROUND_TRUTH

    settings = _spec(args)
    made = _made_from(args.model, [args.data], settings)
    figures = _files(args.phi_out, "figure of predicted Φ", FIGURE_SUFFIXES, "--phi-out", made)
    figures += _files(args.curves_out, "figure of training curves", FIGURE_SUFFIXES,
                      "--curves-out", made)  # fmt: skip
    claim(args, *figures)
    models = _load_models(args.model)
    colors, labels = settings.colors_labels(list(models))
    data = _read_dataset(args.data)
    phis = {}
    for name, model in models.items():
        windows = make_windows(data, model.history)
        phis[name] = (list(model.param_names), predict_phi(model, windows.features))
    # align on the common time axis: the label step of each window
    shortest = min(len(phi) for _, phi in phis.values())
    aligned = {n: (pn, phi[-shortest:]) for n, (pn, phi) in phis.items()}
    time = data["time"][-shortest:]
    steps = np.arange(data["inputs"].shape[1])[-shortest - 1 : -1]
    frx = drivetrain_force(
        data["dstates"][3, steps], data["inputs"][0, steps], GROUND_TRUTH.as_dict()
    )
    save_figure(plot_phi(aligned, time, colors, labels, settings.ts, frx), *args.phi_out)
    losses, best = {}, {}
    for item in args.model:
        name, _, folder = item.partition("=")
        losses[name], meta = read_training(folder)
        best[name] = int(meta["best_epoch"])
    save_figure(plot_training_curves(losses, best, colors, labels), *args.curves_out)
    print("wrote " + ", ".join([*args.phi_out, *args.curves_out]))
