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

It reads the training set the workflow builds (`snakemake --cores 2 results/data/DYN-PP-ETHZ.npz`)
and each folder's ``health.json`` if there is one (whether the training failed, and why).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from cape.config import load_config, section
from cape.errors import CapeError
from cape.models.checkpoint import load_model
from cape.models.training import TrainingData
from cape.vehicle.params import GROUND_TRUTH

REPO = Path(__file__).resolve().parents[1]


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
    health = folder / "health.json"
    said = json.loads(health.read_text()) if health.is_file() else {}
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, help="training folders (model.pt)")
    parser.add_argument("--data", type=Path, default=REPO / "results/data/DYN-PP-ETHZ.npz")
    parser.add_argument("--config", type=Path, default=REPO / "config/config.yaml")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    try:
        config = load_config(args.config)
        if not args.data.is_file():
            raise CapeError(
                f"{args.data}: missing; build it with `snakemake --cores 2 {args.data}`"
            )
        with np.load(args.data) as npz:
            data = {k: npz[k] for k in npz.files}
        for folder in args.folders:
            diagnose(folder, data, config)
    except CapeError as exc:
        print(f"ddm_stall.py: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
