"""Training a learned model on the ETHZ windows (SPEC §3–§4).

CPU only, seeded and deterministic: the same config and seed give the same losses bit for bit.
MSE on the unscaled next [vx, vy, ω]; Adam; the checkpoint of best validation loss is kept.
"""

from __future__ import annotations

import copy
import hashlib
import io
import json
import os
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from cape.data.windows import StandardScaler, WindowSet, make_windows, split_indices
from cape.errors import CapeError
from cape.io import write_bytes
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
    resumed_from: int = 0
    """The epoch a checkpoint had completed when this training resumed from it (0: none)."""


@dataclass(frozen=True)
class Checkpointing:
    """Where an interrupted training resumes from (``path``), and how often it is written.

    The checkpoint holds everything the next epoch depends on (weights, Adam's state, the
    best weights so far, the losses, the batch-order and global RNG states, the epoch), so a
    resumed training continues on exactly the path of an uninterrupted one: the same losses
    bit for bit and a byte-identical ``model.pt``. ``fingerprint`` names what it was written
    for (the model, its recipe, the seed, the data, the threads and kernels); a checkpoint of
    anything else is refused, never resumed."""

    path: Path
    fingerprint: str
    every_seconds: float = 60.0

    def load(self) -> dict[str, Any] | None:
        """The checkpoint's state, None if there is none, ``CapeError`` if it is not this
        training's."""
        if not self.path.is_file():
            return None
        fix = f"delete it (`rm {self.path}`) to train from the start"
        try:
            state = torch.load(self.path, map_location="cpu", weights_only=True)
        except Exception as exc:  # torch raises several types for a damaged file
            raise CapeError(f"{self.path}: not a readable checkpoint ({exc}); {fix}") from exc
        if not isinstance(state, dict) or state.get("fingerprint") != self.fingerprint:
            raise CapeError(
                f"{self.path}: a checkpoint of another training (another config, data set or "
                f"seed), not resumed; {fix}"
            )
        return state

    def save(self, state: dict[str, Any]) -> None:
        """Write ``state`` atomically (an interrupted write leaves the previous checkpoint)."""
        buffer = io.BytesIO()
        torch.save({**state, "fingerprint": self.fingerprint}, buffer)
        write_bytes(self.path, buffer.getvalue())


def training_fingerprint(**what: Any) -> str:
    """A digest of everything a training's result depends on (JSON-serialisable values)."""
    text = json.dumps(what, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


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
    compile_settings: Mapping[str, Any] | None = None,
    checkpoint: Checkpointing | None = None,
) -> TrainingResult:
    """Train model ``name`` with hyper-parameters ``spec`` (``epochs`` overrides the spec's).
    ``fused``: Adam's fused kernel (one pass over all parameters instead of a loop over the
    tensors: the same update up to rounding, 1.4× faster steps for EPM on one CPU thread).
    ``compile_settings`` (``training.compile``): the training forward and backward compiled by
    ``torch.compile`` (the same recipe; losses agree with eager ones to about 1e-6 relative).
    ``checkpoint``: resume from it if it exists, and write it every ``every_seconds``."""
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

    forward = training_forward(model, compile_settings)
    result = TrainingResult(model=model)
    best_state: dict[str, torch.Tensor] | None = None
    start = time.perf_counter()
    earlier = 0.0  # wall seconds spent before a resume
    state = checkpoint.load() if checkpoint is not None else None
    if state is not None:
        model.load_state_dict(state["model"])
        optimiser.load_state_dict(state["optimiser"])
        generator.set_state(state["generator"])
        torch.set_rng_state(state["rng"])
        best_state = state["best_state"]
        result.losses = list(state["losses"])
        result.best_epoch, result.best_val_loss = state["best_epoch"], state["best_val_loss"]
        result.resumed_from, earlier = len(result.losses), float(state["wall_seconds"])
    saved = time.perf_counter()
    bar = tqdm(
        range(result.resumed_from + 1, n_epochs + 1),
        desc=f"train {name}",
        unit="epoch",
        initial=result.resumed_from,
        total=n_epochs,
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
            loss = torch.mean((forward(x_train[idx]) - y_train[idx]) ** 2)
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
        now = time.perf_counter()
        if checkpoint is not None and epoch < n_epochs and now - saved >= checkpoint.every_seconds:
            checkpoint.save({
                "model": model.state_dict(),
                "optimiser": optimiser.state_dict(),
                "generator": generator.get_state(),
                "rng": torch.get_rng_state(),
                "best_state": best_state,
                "losses": result.losses,
                "best_epoch": result.best_epoch,
                "best_val_loss": result.best_val_loss,
                "wall_seconds": earlier + now - start,
            })  # fmt: skip
            saved = time.perf_counter()
    if best_state is not None:
        model.load_state_dict(best_state)
    model.eval()
    result.wall_seconds = earlier + time.perf_counter() - start
    return result


def training_forward(
    model: LearnedModel, settings: Mapping[str, Any] | None
) -> Callable[[torch.Tensor], torch.Tensor]:
    """The model's forward for the training steps: the model itself, or (``enabled``) compiled.

    Why compiled: eager PyTorch runs the GRU as dozens of tiny cells, each a handful of ATen
    calls and autograd nodes, so a step costs the per-operation overhead; the compiled graph
    fuses them (measured per step on one thread: EPM 1.8×, DPM 2.4×, DDM 1.35× faster;
    ``benchmarks/training_step.py``). Dynamo traces through ``nn.GRU`` only with ``allow_rnn``.
    The graph is static per batch size (the last, shorter batch of an epoch compiles once
    more); validation stays eager, so only training steps meet the compiled code. Inductor's
    cache lives under ``cache`` (kept between runs, so a rerun compiles in seconds, not the
    70–140 s of a cold cache)."""
    if not settings or not settings.get("enabled", False):
        return model
    import torch._dynamo

    if settings.get("cache"):
        os.environ["TORCHINDUCTOR_CACHE_DIR"] = str(Path(settings["cache"]).resolve())
    try:  # before any tracing: a missing compiler fails in a moment, not after the codegen
        from torch._inductor.cpp_builder import get_cpp_compiler

        get_cpp_compiler()
    except Exception as error:  # Inductor's own exception types are private
        raise _compile_error(error) from error
    torch._dynamo.config.allow_rnn = True
    compiled = torch.compile(model, dynamic=False)
    checked: set[int] = set()

    def forward(windows: torch.Tensor) -> torch.Tensor:
        if len(windows) in checked:
            return compiled(windows)
        try:  # a new shape: this call compiles
            out = compiled(windows)
        except Exception as error:  # Inductor raises many kinds; one fix
            raise _compile_error(error) from error
        checked.add(len(windows))
        return out

    return forward


def _compile_error(error: Exception) -> CapeError:
    first = str(error).strip().splitlines()[0][:300] if str(error).strip() else ""
    return CapeError(
        f"training.compile: PyTorch could not compile the training step "
        f"({type(error).__name__}: {first}). It needs a C++ compiler (g++ or clang++, or $CXX); "
        "install one, or set `training.compile.enabled: false` in config/config.yaml to train "
        "eagerly (the same recipe, slower)."
    )
