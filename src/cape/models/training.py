"""Training a learned model on the ETHZ windows (SPEC §3–§4).

CPU only, seeded and deterministic: the same config and seed give the same losses bit for bit.
MSE on the unscaled next [vx, vy, ω]; Adam; the checkpoint of best validation loss is kept.
"""

from __future__ import annotations

import copy
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from cape.data.windows import StandardScaler, WindowSet, make_windows, split_indices
from cape.models.base import LearnedModel
from cape.models.registry import model_class


@dataclass
class TrainingData:
    """Training and validation windows of one history length, and the scaler of the former."""

    train: WindowSet
    val: WindowSet
    scaler: StandardScaler

    @classmethod
    def from_dataset(
        cls, dataset: dict[str, np.ndarray], history: int, train_fraction: float, seed: int
    ) -> TrainingData:
        windows = make_windows(dataset, history)
        train_idx, val_idx = split_indices(len(windows), train_fraction, seed)
        train = windows.subset(train_idx)
        return cls(
            train=train, val=windows.subset(val_idx), scaler=StandardScaler.fit(train.features)
        )


@dataclass
class TrainingResult:
    model: LearnedModel
    losses: list[dict[str, float]] = field(default_factory=list)
    best_epoch: int = 0
    best_val_loss: float = float("inf")
    wall_seconds: float = 0.0


def build_model(name: str, spec: dict[str, Any], ts: float, seed: int) -> LearnedModel:
    """A freshly initialised model; the seed fixes its initial weights."""
    torch.manual_seed(seed)
    return LearnedModel(model_class(name, spec)(spec, ts))


def train_model(
    name: str,
    spec: dict[str, Any],
    data: TrainingData,
    *,
    ts: float,
    seed: int,
    epochs: int | None = None,
    threads: int = 1,
    progress: bool = True,
    fused: bool = True,
) -> TrainingResult:
    """Train model ``name`` with hyper-parameters ``spec`` (``epochs`` overrides the spec's).
    ``fused``: Adam's fused kernel (one pass over all parameters instead of a loop over the
    tensors: the same update up to rounding, 1.4× faster steps for EPM on one CPU thread)."""
    torch.set_num_threads(threads)
    torch.use_deterministic_algorithms(True)
    model = build_model(name, spec, ts, seed)
    model.set_scaler(data.scaler.mean, data.scaler.scale)
    hyper = spec["train"]
    n_epochs = int(epochs if epochs is not None else hyper["epochs"])
    batch = int(hyper["batch_size"])
    optimiser = torch.optim.Adam(model.parameters(), lr=float(hyper["lr"]), fused=fused)
    generator = torch.Generator().manual_seed(seed)

    x_train = torch.as_tensor(data.train.features, dtype=torch.float64)
    y_train = torch.as_tensor(data.train.labels, dtype=torch.float64)
    x_val = torch.as_tensor(data.val.features, dtype=torch.float64)
    y_val = torch.as_tensor(data.val.labels, dtype=torch.float64)

    result = TrainingResult(model=model)
    best_state: dict[str, torch.Tensor] | None = None
    start = time.perf_counter()
    bar = tqdm(
        range(1, n_epochs + 1),
        desc=f"train {name}",
        unit="epoch",
        disable=not progress,
        mininterval=0.5 if sys.stderr.isatty() else 30.0,
        file=sys.stderr,
    )
    for epoch in bar:
        model.train()
        order = torch.randperm(len(x_train), generator=generator)
        total, count = 0.0, 0
        for first in range(0, len(order), batch):
            idx = order[first : first + batch]
            loss = torch.mean((model(x_train[idx]) - y_train[idx]) ** 2)
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            total += loss.item() * len(idx)
            count += len(idx)
        model.eval()
        with torch.no_grad():
            val_loss = float(torch.mean((model(x_val) - y_val) ** 2))
        train_loss = total / count
        result.losses.append({"epoch": epoch, "train_loss": train_loss, "val_loss": val_loss})
        if val_loss < result.best_val_loss:
            result.best_val_loss, result.best_epoch = val_loss, epoch
            best_state = copy.deepcopy(model.state_dict())
        bar.set_postfix(
            train=f"{train_loss:.3e}",
            val=f"{val_loss:.3e}",
            best=f"{result.best_val_loss:.3e}@{result.best_epoch}",
            refresh=False,  # the bar's own interval decides when to redraw
        )
    if best_state is not None:
        model.load_state_dict(best_state)
    model.eval()
    result.wall_seconds = time.perf_counter() - start
    return result
