"""Cost of one training step per model, the previous compiled step against today's, in one process.

- ``old``: issue 15's step: ``torch.compile`` of the model's forward (``nn.GRU`` unrolled cell by
  cell, a second graph for the shorter last batch), the batch gathered and the MSE taken eagerly,
  ``optimiser.step()``.
- ``new``: the step ``cape train`` runs (``cape.training.loop``): the whole batch loss compiled
  (gather, stage-by-stage GRU, physics, MSE over the real rows of a padded batch), Inductor's
  C++ wrapper as ``training.compile`` says, the fused Adam update without its Python bookkeeping.
- ``eager`` (``--eager``): the new loss, not compiled.

The variants train copies of the same initial model on the same batches, interleaved in rounds so
that drift of a shared machine falls on all; the script prints CPU ms per step (this process's
user + system time) and wall ms per round, the median ratio old/new, and the largest relative
difference of the losses (new vs old: the float path changed, so they drift apart as training
goes on; a few steps show the size of one step's rounding).

    python benchmarks/training_step.py [--models epm dpm ddm] [--epochs 2] [--rounds 5]
                                       [--variants old new eager] [--steps N]

``--variants eager`` alone compiles nothing (a quick check that the steps run); ``--steps N``
takes only the first N batches of an epoch. It reads the training set the workflow builds
(`snakemake --cores 2 results/data/DYN-PP-ETHZ.npz`, ``cape.layout.paths.dataset``; run it from
the study's folder) and compiles into ``training.compile.cache``. The first call of each
compiled variant compiles (seconds with a warm cache, minutes cold): it is timed apart (wall
and this process's CPU; the C++ compiler runs in child processes) and not counted in the
per-step figures.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch
from _common import add_config, run, study_config  # a sibling module

from cape.config import section
from cape.data.bayesrace import read_dataset
from cape.errors import CapeError
from cape.layout import paths
from cape.specs.training import TrainingCompile
from cape.training.loop import (
    AdamStep,
    PaddedBatches,
    TrainingData,
    build_model,
    training_loss,
)

VARIANTS = ("old", "new", "eager")
Step = Callable[[torch.Tensor], float]


def _old_stepper(name, spec, data, ts, settings) -> Step:
    """Issue 15's training step, as it was."""
    import torch._dynamo

    model = build_model(name, spec, ts, seed=0)
    model.set_scaler(data.scaler.mean, data.scaler.scale)
    model.train()
    optimiser = torch.optim.Adam(model.parameters(), lr=float(spec["train"]["lr"]), fused=True)
    if settings.cache:
        os.environ["TORCHINDUCTOR_CACHE_DIR"] = str(Path(settings.cache).resolve())
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
    """The step of ``cape.training.loop.train_model``."""
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
    parser.add_argument("--variants", nargs="+", choices=VARIANTS, default=["old", "new"],
                        help="the steps to time (default: old new)")  # fmt: skip
    parser.add_argument("--eager", action="store_true", help="also time the new step uncompiled")
    parser.add_argument("--steps", type=int, help="only the first N batches of an epoch")
    parser.add_argument(
        "--data", type=Path, help="the training set (default: the workflow's, of data.train_track)"
    )
    add_config(parser)
    args = parser.parse_args()
    if args.epochs < 1 or args.rounds < 1 or (args.steps is not None and args.steps < 1):
        parser.error("--epochs, --rounds and --steps: give at least 1")
    variants = list(dict.fromkeys([*args.variants, *(["eager"] if args.eager else [])]))
    config = study_config(args)
    data_cfg, train_cfg = section(config, "data"), section(config, "training")
    unknown = [m for m in args.models if m not in config["models"]]
    if unknown:
        raise CapeError(f"--models {' '.join(unknown)}: not in the config's `models` "
                        f"({', '.join(config['models'])})")  # fmt: skip
    torch.set_num_threads(int(train_cfg["threads"]))
    torch.use_deterministic_algorithms(True)  # as cape train runs
    dataset = read_dataset(args.data or paths.dataset(data_cfg["train_track"]))
    settings = dataclasses.replace(TrainingCompile.from_config(config), enabled=True)
    print(f"training.compile: {settings}; {torch.get_num_threads()} thread(s); load average "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}")  # fmt: skip
    ts = float(data_cfg["ts"])
    makers = {"old": lambda *a: _old_stepper(*a, settings),
              "new": lambda *a: _new_stepper(*a, settings),
              "eager": lambda *a: _new_stepper(*a, None)}  # fmt: skip
    for name in args.models:
        spec = config["models"][name]
        split = data_cfg["split"]
        data = TrainingData.from_dataset(
            dataset, int(spec["history"]), float(split["train_fraction"]), int(split["seed"])
        )
        batch = int(spec["train"]["batch_size"])
        order = torch.randperm(len(data.train), generator=torch.Generator().manual_seed(0))
        epoch = [order[i : i + batch] for i in range(0, len(order), batch)]
        batches = epoch[: args.steps] * args.epochs
        steppers = {label: makers[label](name, spec, data, ts) for label in variants}
        losses: dict[str, list[float]] = {label: [] for label in steppers}
        for label, step in steppers.items():
            wall, cpu = time.perf_counter(), _cpu()
            losses[label] += [step(epoch[0]), step(epoch[-1])]  # both batch sizes
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
        medians = {label: statistics.median(v) for label, v in cpu_ms.items()}
        ratio = ""
        if "old" in cpu_ms and "new" in cpu_ms:
            ratios = [a / b for a, b in zip(cpu_ms["old"], cpu_ms["new"], strict=True)]
            ratio = f"; median ratio old/new {statistics.median(ratios):.2f}"
        print("  median CPU ms/step: " + ", ".join(f"{k} {v:.2f}" for k, v in medians.items())
              + ratio)  # fmt: skip
        base = variants[0]
        for label in losses:
            if label == base:
                continue
            pairs = list(zip(losses[label], losses[base], strict=True))
            first = max(abs(a - b) / abs(b) for a, b in pairs[:4])
            worst = max(abs(a - b) / abs(b) for a, b in pairs)
            print(f"  {label} vs {base} losses: largest relative difference {first:.1e} over the "
                  f"first 4 steps, {worst:.1e} over all {len(pairs)}")  # fmt: skip
        if base == "old" and {"new", "eager"} <= losses.keys():
            pairs = list(zip(losses["new"], losses["eager"], strict=True))
            worst = max(abs(a - b) / abs(b) for a, b in pairs)
            print(f"  new vs eager losses: largest relative difference {worst:.1e}")


if __name__ == "__main__":
    sys.exit(run(main))
