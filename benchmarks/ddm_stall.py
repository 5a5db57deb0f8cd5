"""Why a training stalls: where the gradient vanishes, and what the physics guard outputs.

For each training folder (``results/trainings/<model>/seed<s>``, as the workflow writes them) the
script loads the network ``model.pt`` holds (the best validation epoch's weights), computes the
plain MSE over the ETHZ training windows (the loss of SPEC §4.2) and its gradient, and prints:

- per block (the GRU, each trunk layer, the guard's linear layer): the gradient's norm, and its
  norm relative to the weights' (how far one unit-rate step would move them);
- the guard: per output, the mean and spread over the windows of σ (its position between the
  bounds), of σ' = σ(1 − σ) (the factor every gradient through it is multiplied by) and where
  the true parameter (SPEC §1) lies between the same bounds;
- the spread of the trunk's last activations over the windows (a network whose output no longer
  depends on its input has collapsed to a constant Φ).

    python benchmarks/ddm_stall.py results/trainings/ddm/seed0 results/trainings/ddm/seed1 ...

With ``--early MODEL … --seeds N`` it instead retrains each named model entry (e.g. ``ddm`` and
the tuned ``ddm_tuned`` of ``config/examples/ddm_tuned.yaml``, merged by ``--overlay``) for its
first ``--epochs`` epochs (2), uncompiled, for seeds ``training.seed`` … + N − 1, and records
after every step the guard's largest pre-activation and the share of its outputs whose slope σ′
is below 1e-6: a training whose every guard output saturates has a gradient of exactly zero in
float32, and Adam's decaying moments never bring it back, so "dead after epoch 2" predicts the
stalled loss of the whole training at a fraction of its cost:

    python benchmarks/ddm_stall.py --early ddm ddm_tuned --seeds 12 \
        --overlay config/examples/ddm_tuned.yaml

It reads the training set the workflow builds (`snakemake --cores 2 results/data/DYN-PP-ETHZ.npz`,
``cape.layout.paths.dataset``; run it from the study's folder) and each folder's ``health.json``
if there is one (whether the training failed, and why).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
from _common import add_config, run, study_config  # a sibling module

from cape.config import section
from cape.data.bayesrace import read_dataset
from cape.errors import CapeError
from cape.layout import paths
from cape.storage.io import read_json
from cape.training.checkpoint import load_model
from cape.training.loop import TrainingData
from cape.vehicle.params import GROUND_TRUTH


def _blocks(model: torch.nn.Module) -> list[tuple[str, list[torch.nn.Parameter]]]:
    """The network's parameters grouped as the stall is read: GRU, trunk layers, guard."""
    blocks: list[tuple[str, list[torch.nn.Parameter]]] = []
    if model.gru is not None:
        blocks.append(("gru", list(model.gru.parameters())))
    linear = 0
    for layer in model.trunk:
        params = list(layer.parameters())
        if params:
            linear += isinstance(layer, torch.nn.Linear)
            blocks.append((f"trunk {linear} ({type(layer).__name__})", params))
    blocks.append(("guard linear", list(model.output.parameters())))
    return blocks


def diagnose(folder: Path, data: dict[str, np.ndarray], config: dict) -> None:
    if not (folder / paths.WEIGHTS).is_file():
        raise CapeError(f"{folder}: no model.pt, so not a training folder; give one of "
                        f"{paths.TRAINING.format(model='<model>', training_seed='<s>')} "
                        "(`snakemake --cores 2` trains them)")  # fmt: skip
    model = load_model(folder)
    model.train(False)
    split = section(config, "data")["split"]
    windows = TrainingData.from_dataset(
        data, model.history, float(split["train_fraction"]), int(split["seed"])
    ).train
    x = torch.as_tensor(windows.features, dtype=torch.float64)
    y = torch.as_tensor(windows.labels, dtype=torch.float64)
    model.zero_grad()
    loss = torch.mean((model(x) - y) ** 2)
    loss.backward()
    health = folder / paths.HEALTH
    fix = f"delete it and rebuild it with `snakemake --cores 2 {health}`"
    said = read_json(health, "a training's health record", fix) if health.is_file() else {}
    outcome = (
        "no health.json"
        if not said
        else ("trained" if said.get("trained") else "failed: " + "; ".join(said.get("reasons", [])))
    )
    print(f"\n== {folder}: {len(x)} training windows, MSE {loss.item():.4e}; {outcome}")
    print(f"{'block':<28} {'|grad|':>10} {'|grad|/|w|':>11}")
    for name, params in _blocks(model):
        grads = [p.grad for p in params if p.grad is not None]
        g = float(torch.sqrt(sum((q.double() ** 2).sum() for q in grads))) if grads else 0.0
        w = float(torch.sqrt(sum((p.detach().double() ** 2).sum() for p in params)))
        print(f"{name:<28} {g:>10.3e} {g / max(w, 1e-30):>11.3e}")
    with torch.no_grad():
        scaled = ((x - model.feature_mean) / model.feature_scale).to(torch.float32)
        hidden = model.gru(scaled)[0] if model.gru is not None else scaled
        last = model.trunk(hidden.reshape(hidden.shape[0], -1))
        guard = getattr(model.output, "linear", None)
        spread, size = float(last.std(0).mean()), float(last.abs().mean())
        print(f"trunk output: a unit's sd over the windows {spread:.3e}, mean |value| {size:.3e}")
        if guard is None:
            return
        sigma = torch.sigmoid(guard(last)).double()
        slope = sigma * (1 - sigma)
        lower, upper = model.output.lower, model.output.upper
    print(f"{'Φ':<5} {'σ mean':>8} {'σ sd':>9} {'σ′ mean':>9} {'true at':>8}")
    for k, name in enumerate(model.param_names):
        true = getattr(GROUND_TRUTH, name, None)
        where = (
            f"{(true - float(lower[k])) / float(upper[k] - lower[k]):>8.3f}"
            if true is not None
            else f"{'–':>8}"
        )
        print(
            f"{name:<5} {float(sigma[:, k].mean()):>8.3f} {float(sigma[:, k].std()):>9.2e} "
            f"{float(slope[:, k].mean()):>9.2e} {where}"
        )


def early(
    name: str, spec: dict, data: dict[str, np.ndarray], config: dict, seed: int, epochs: int
) -> dict[str, object]:
    """Train ``name`` for ``epochs`` epochs, uncompiled, hooking the guard: whether every guard
    output is saturated at the end, the step it first was, the largest pre-activation and the
    training loss per epoch."""
    import cape.training.loop as training

    split = section(config, "data")["split"]
    windows = TrainingData.from_dataset(
        data, int(spec["history"]), float(split["train_fraction"]), int(split["seed"])
    )
    steps: list[tuple[float, float]] = []

    def hook(module: torch.nn.Module, inputs: tuple, out: torch.Tensor) -> None:
        if torch.is_grad_enabled():  # a training step, not the validation pass
            z = out.detach()
            slope = torch.sigmoid(z) * (1 - torch.sigmoid(z))
            steps.append((float(z.abs().max()), float((slope < 1e-6).double().mean())))

    build = training.build_model

    def hooked(*args: object, **kwargs: object) -> torch.nn.Module:
        model = build(*args, **kwargs)
        model.output.linear.register_forward_hook(hook)
        return model

    training.build_model = hooked
    try:
        result = training.train_model(
            name, spec, windows, ts=float(section(config, "data")["ts"]), seed=seed,
            epochs=epochs, progress=False, compile_settings=None,
        )  # fmt: skip
    finally:
        training.build_model = build
    dead = [i for i, (_, share) in enumerate(steps) if share == 1.0]
    return {
        "model": name,
        "seed": seed,
        "dead": bool(steps) and steps[-1][1] == 1.0,
        "first dead step": dead[0] if dead else "",
        "largest |z|": f"{max(z for z, _ in steps):.3g}",
        "saturated at the end": f"{steps[-1][1]:.0%}" if steps else "",
        "train loss per epoch": ", ".join(f"{e['train_loss']:.3g}" for e in result.losses),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="*", type=Path, help="training folders (model.pt)")
    parser.add_argument("--early", nargs="+", metavar="MODEL", help="retrain these entries' start")
    parser.add_argument("--seeds", type=int, default=6, help="with --early: seeds per model")
    parser.add_argument("--epochs", type=int, default=2, help="with --early: epochs per seed")
    parser.add_argument(
        "--data", type=Path, help="the training set (default: the workflow's, of data.train_track)"
    )
    add_config(parser)
    args = parser.parse_args()
    if not args.folders and not args.early:
        parser.error("give training folders, or --early MODEL …")
    if args.seeds < 1 or args.epochs < 1:
        parser.error("--seeds and --epochs: give at least 1")
    torch.set_num_threads(1)
    config = study_config(args)
    path = args.data or Path(paths.dataset(section(config, "data")["train_track"]))
    data = read_dataset(path)
    for folder in args.folders:
        diagnose(folder, data, config)
    first = int(section(config, "training")["seed"])
    rows = []
    for name in args.early or []:
        spec = section(config, "models").get(name)
        if spec is None:
            raise CapeError(f"--early {name}: no such model entry (give --configfile?)")
        for seed in range(first, first + args.seeds):
            rows.append(early(name, spec, data, config, seed, args.epochs))
            print(" | ".join(str(v) for v in rows[-1].values()), flush=True)
    for name in args.early or []:
        mine = [r for r in rows if r["model"] == name]
        print(f"{name}: dead after {args.epochs} epochs in "
              f"{sum(bool(r['dead']) for r in mine)} of {len(mine)} seeds")  # fmt: skip


if __name__ == "__main__":
    sys.exit(run(main))
