"""Cost of one training step per model, eager against torch.compile'd (issue 15), in one process.

The two variants train copies of the same initial model on the same batches, interleaved in
rounds so that drift of a shared machine falls on both; the script prints ms per step per round,
the median ratio and the largest relative difference of the losses.

    python benchmarks/training_step.py [--models epm dpm ddm] [--epochs 2] [--rounds 4]

It reads the training set the workflow builds (`snakemake --cores 2 results/data/DYN-PP-ETHZ.npz`).
The first compiled call compiles (seconds with a warm cache, a minute or two cold): it is timed
apart and not counted in the per-step figures.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from cape.config import load_config, section
from cape.models.training import TrainingData, build_model, training_forward

REPO = Path(__file__).resolve().parents[1]


def _stepper(name, spec, data, ts, settings):
    model = build_model(name, spec, ts, seed=0)
    model.set_scaler(data.scaler.mean, data.scaler.scale)
    model.train()
    optimiser = torch.optim.Adam(model.parameters(), lr=float(spec["train"]["lr"]), fused=True)
    forward = training_forward(model, settings)
    x = torch.as_tensor(data.train.features, dtype=torch.float64)
    y = torch.as_tensor(data.train.labels, dtype=torch.float64)

    def step(idx: torch.Tensor) -> float:
        loss = torch.mean((forward(x[idx]) - y[idx]) ** 2)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        return loss.item()

    return step


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["epm", "dpm", "ddm"])
    parser.add_argument("--epochs", type=int, default=2, help="epochs per round and variant")
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--data", default="results/data/DYN-PP-ETHZ.npz")
    args = parser.parse_args()
    config = load_config(REPO / "config" / "config.yaml")
    data_cfg, train_cfg = section(config, "data"), section(config, "training")
    torch.set_num_threads(int(train_cfg["threads"]))
    with np.load(args.data) as npz:
        dataset = {k: npz[k] for k in npz.files}
    settings = {**(train_cfg.get("compile") or {}), "enabled": True}
    for name in args.models:
        spec = config["models"][name]
        split = data_cfg["split"]
        data = TrainingData.from_dataset(
            dataset, int(spec["history"]), float(split["train_fraction"]), int(split["seed"])
        )
        batch = int(spec["train"]["batch_size"])
        order = torch.randperm(len(data.train), generator=torch.Generator().manual_seed(0))
        batches = [order[i : i + batch] for i in range(0, len(order), batch)] * args.epochs
        eager = _stepper(name, spec, data, float(data_cfg["ts"]), None)
        compiled = _stepper(name, spec, data, float(data_cfg["ts"]), settings)
        start = time.perf_counter()
        compiled(batches[0]), compiled(batches[-1])  # both shapes: the full and the last batch
        eager(batches[0]), eager(batches[-1])
        print(f"{name}: compile {time.perf_counter() - start:.1f} s; {len(batches)} steps/round")
        losses: dict[str, list[float]] = {"eager": [], "compiled": []}
        ratios = []
        for r in range(args.rounds):
            ms = {}
            for label, step in (("eager", eager), ("compiled", compiled)):
                start = time.perf_counter()
                losses[label] += [step(b) for b in batches]
                ms[label] = (time.perf_counter() - start) / len(batches) * 1e3
            ratios.append(ms["eager"] / ms["compiled"])
            print(f"  round {r}: eager {ms['eager']:.2f} ms/step, compiled "
                  f"{ms['compiled']:.2f} ms/step, ratio {ratios[-1]:.2f}")  # fmt: skip
        pairs = zip(losses["compiled"], losses["eager"], strict=True)
        worst = max(abs(a - b) / abs(b) for a, b in pairs)
        print(f"  median ratio {statistics.median(ratios):.2f}; largest relative loss "
              f"difference {worst:.2e}")  # fmt: skip


if __name__ == "__main__":
    main()
