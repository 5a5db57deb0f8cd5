"""Cost of one training step per model, the previous compiled step against today's, in one process.

- ``old``: issue 15's step: ``torch.compile`` of the model's forward (``nn.GRU`` unrolled cell by
  cell, a second graph for the shorter last batch), the batch gathered and the MSE taken eagerly,
  ``optimiser.step()``.
- ``new``: the step ``cape train`` runs (``cape.models.training``): the whole batch loss compiled
  (gather, stage-by-stage GRU, physics, MSE over the real rows of a padded batch), Inductor's
  C++ wrapper as ``training.compile`` says, the fused Adam update without its Python bookkeeping.
- ``eager`` (``--eager``): the new loss, not compiled.

The variants train copies of the same initial model on the same batches, interleaved in rounds so
that drift of a shared machine falls on all; the script prints CPU ms per step (this process's
user + system time) and wall ms per round, the median ratio old/new, and the largest relative
difference of the losses (new vs old: the float path changed, so they drift apart as training
goes on; a few steps show the size of one step's rounding).

    python benchmarks/training_step.py [--models epm dpm ddm] [--epochs 2] [--rounds 5]

It reads the training set the workflow builds (`snakemake --cores 2 results/data/DYN-PP-ETHZ.npz`)
and compiles into ``training.compile.cache``. The first call of each compiled variant compiles
(seconds with a warm cache, minutes cold): it is timed apart (wall and this process's CPU; the
C++ compiler runs in child processes) and not counted in the per-step figures.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from cape.config import load_config, section
from cape.models.training import (
    AdamStep,
    PaddedBatches,
    TrainingData,
    build_model,
    training_loss,
)

REPO = Path(__file__).resolve().parents[1]
Step = Callable[[torch.Tensor], float]


def _old_stepper(name, spec, data, ts, settings) -> Step:
    """Issue 15's training step, as it was."""
    import torch._dynamo

    model = build_model(name, spec, ts, seed=0)
    model.set_scaler(data.scaler.mean, data.scaler.scale)
    model.train()
    optimiser = torch.optim.Adam(model.parameters(), lr=float(spec["train"]["lr"]), fused=True)
    if settings.get("cache"):
        os.environ["TORCHINDUCTOR_CACHE_DIR"] = str(Path(settings["cache"]).resolve())
    torch._dynamo.config.allow_rnn = True
    forward = torch.compile(model, dynamic=False, options={"cpp_wrapper": False})
    x = torch.as_tensor(data.train.features, dtype=torch.float64)
    y = torch.as_tensor(data.train.labels, dtype=torch.float64)

    def step(idx: torch.Tensor) -> float:
        loss = torch.mean((forward(x[idx]) - y[idx]) ** 2)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        return loss.item()

    return step


def _new_stepper(name, spec, data, ts, settings) -> Step:
    """The step of ``cape.models.training.train_model``."""
    model = build_model(name, spec, ts, seed=0)
    model.set_scaler(data.scaler.mean, data.scaler.scale)
    model.train()
    optimiser = torch.optim.Adam(model.parameters(), lr=float(spec["train"]["lr"]), fused=True)
    update = AdamStep(optimiser)
    x = torch.as_tensor(data.train.features, dtype=torch.float64)
    y = torch.as_tensor(data.train.labels, dtype=torch.float64)
    loss_of = training_loss(model, x, y, settings)
    batches = PaddedBatches(int(spec["train"]["batch_size"]))

    def step(idx: torch.Tensor) -> float:
        ((index, mask, count, _),) = batches.of(idx)
        loss = loss_of(index, mask, count)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        update()
        return loss.item()

    return step


def _cpu() -> float:
    return time.process_time()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["epm", "dpm", "ddm"])
    parser.add_argument("--epochs", type=int, default=2, help="epochs per round and variant")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--eager", action="store_true", help="also time the new step uncompiled")
    parser.add_argument("--data", default="results/data/DYN-PP-ETHZ.npz")
    args = parser.parse_args()
    config = load_config(REPO / "config" / "config.yaml")
    data_cfg, train_cfg = section(config, "data"), section(config, "training")
    torch.set_num_threads(int(train_cfg["threads"]))
    torch.use_deterministic_algorithms(True)  # as cape train runs
    with np.load(args.data) as npz:
        dataset = {k: npz[k] for k in npz.files}
    settings = {**(train_cfg.get("compile") or {}), "enabled": True}
    print(f"training.compile: {settings}; {torch.get_num_threads()} thread(s); load average "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}")  # fmt: skip
    ts = float(data_cfg["ts"])
    for name in args.models:
        spec = config["models"][name]
        split = data_cfg["split"]
        data = TrainingData.from_dataset(
            dataset, int(spec["history"]), float(split["train_fraction"]), int(split["seed"])
        )
        batch = int(spec["train"]["batch_size"])
        order = torch.randperm(len(data.train), generator=torch.Generator().manual_seed(0))
        batches = [order[i : i + batch] for i in range(0, len(order), batch)] * args.epochs
        steppers = {
            "old": _old_stepper(name, spec, data, ts, settings),
            "new": _new_stepper(name, spec, data, ts, settings),
        }
        if args.eager:
            steppers["eager"] = _new_stepper(name, spec, data, ts, None)
        losses: dict[str, list[float]] = {label: [] for label in steppers}
        for label, step in steppers.items():
            wall, cpu = time.perf_counter(), _cpu()
            losses[label] += [step(batches[0]), step(batches[-1])]  # both batch sizes
            print(f"{name} {label}: first two steps (compiling) {time.perf_counter() - wall:.1f} s "
                  f"wall, {_cpu() - cpu:.1f} s CPU in this process")  # fmt: skip
        print(f"{name}: {len(batches)} steps per round and variant")
        cpu_ms: dict[str, list[float]] = {label: [] for label in steppers}
        for r in range(args.rounds):
            line = []
            for label, step in steppers.items():
                wall, cpu = time.perf_counter(), _cpu()
                losses[label] += [step(b) for b in batches]
                cpu_ms[label].append((_cpu() - cpu) / len(batches) * 1e3)
                wall_ms = (time.perf_counter() - wall) / len(batches) * 1e3
                line.append(f"{label} {cpu_ms[label][-1]:.2f} CPU / {wall_ms:.2f} wall")
            print(f"  round {r} (ms/step): " + ", ".join(line))
        ratios = [a / b for a, b in zip(cpu_ms["old"], cpu_ms["new"], strict=True)]
        medians = {label: statistics.median(v) for label, v in cpu_ms.items()}
        print("  median CPU ms/step: " + ", ".join(f"{k} {v:.2f}" for k, v in medians.items())
              + f"; median ratio old/new {statistics.median(ratios):.2f}")  # fmt: skip
        for label in losses:
            if label == "old":
                continue
            pairs = list(zip(losses[label], losses["old"], strict=True))
            first = max(abs(a - b) / abs(b) for a, b in pairs[:4])
            worst = max(abs(a - b) / abs(b) for a, b in pairs)
            print(f"  {label} vs old losses: largest relative difference {first:.1e} over the "
                  f"first 4 steps, {worst:.1e} over all {len(pairs)}")  # fmt: skip
        if "eager" in losses:
            pairs = list(zip(losses["new"], losses["eager"], strict=True))
            worst = max(abs(a - b) / abs(b) for a, b in pairs)
            print(f"  new vs eager losses: largest relative difference {worst:.1e}")


if __name__ == "__main__":
    main()
