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
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from cape.data.windows import StandardScaler, WindowSet, make_windows, split_indices
from cape.errors import CapeError
from cape.models.base import LearnedModel
from cape.models.registry import build_physics
from cape.specs.training import TrainingCompile
from cape.storage.io import write_bytes

TRAINING_STEP = 2
"""Version of the training step's arithmetic (1: the batch loss eager around a compiled
forward; 2: the whole padded-batch loss compiled, the GRU stage by stage). It is part
of a checkpoint's fingerprint, so a training never resumes on another step's float path, and
``meta.json`` records it."""


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
    cpu_seconds: float | None = None
    """The process CPU seconds of every part of the training, resumes included (None: a part
    ran before this was recorded)."""
    resumed_from: int = 0
    """The epoch a checkpoint had completed when this training resumed from it (0: none)."""
    rewritten: bool = False
    """Read back whole from the checkpoint a finished training keeps: no epoch was run."""


CHECKPOINT_KEYS = ("model", "optimiser", "generator", "rng", "best_state", "losses",
                   "best_epoch", "best_val_loss", "wall_seconds")  # fmt: skip
"""What a resumed training reads from its checkpoint (and ``cpu_seconds`` where there: a
checkpoint written before CPU was recorded lacks it, and resumes without it)."""


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
                f"{self.path}: a checkpoint of another training (another config, data set, "
                f"seed or kernels), not resumed; {fix}"
            )
        missing = [k for k in CHECKPOINT_KEYS if k not in state]
        if missing:
            raise CapeError(f"{self.path}: lacks {', '.join(missing)}, not resumed; {fix}")
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
    return LearnedModel(build_physics(name, spec, ts))


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
    compile_settings: TrainingCompile | None = None,
    checkpoint: Checkpointing | None = None,
) -> TrainingResult:
    """Train model ``name`` with hyper-parameters ``spec`` (``epochs`` overrides the spec's).
    ``fused``: Adam's fused kernel (one pass over all parameters instead of a loop over the
    tensors: the same update up to rounding, 1.4× faster steps for EPM on one CPU thread).
    ``compile_settings`` (``training.compile``): the training step's loss and its backward
    compiled by ``torch.compile`` (``training_loss``: the same recipe; losses follow eager
    ones to rounding). Every step sees a full batch (``PaddedBatches``: the last one padded
    with rows of mask 0), so the compiled graph has one shape.
    ``checkpoint``: resume from it if it exists, write it every ``every_seconds`` and once
    finished (kept: read back, a finished training's result is the same, record included)."""
    torch.set_num_threads(threads)
    torch.use_deterministic_algorithms(True)
    model = build_model(name, spec, ts, seed)
    model.set_scaler(data.scaler.mean, data.scaler.scale)
    hyper = spec["train"]
    n_epochs = int(epochs if epochs is not None else hyper["epochs"])
    batch = int(hyper["batch_size"])
    optimiser = torch.optim.Adam(model.parameters(), lr=float(hyper["lr"]), fused=fused)
    update = AdamStep(optimiser)
    generator = torch.Generator().manual_seed(seed)

    x_train = torch.as_tensor(data.train.features, dtype=torch.float64)
    y_train = torch.as_tensor(data.train.labels, dtype=torch.float64)
    x_val = torch.as_tensor(data.val.features, dtype=torch.float64)
    y_val = torch.as_tensor(data.val.labels, dtype=torch.float64)

    step_loss = training_loss(model, x_train, y_train, compile_settings)
    result = TrainingResult(model=model)
    best_state: dict[str, torch.Tensor] | None = None
    start = time.perf_counter()
    cpu_start = time.process_time()
    earlier = 0.0  # wall seconds spent before a resume
    earlier_cpu: float | None = 0.0  # CPU seconds spent before a resume (None: not recorded)
    state = checkpoint.load() if checkpoint is not None else None
    finished: tuple[float, int] | None = None  # the record of a training already finished
    if state is not None:
        model.load_state_dict(state["model"])
        optimiser.load_state_dict(state["optimiser"])
        generator.set_state(state["generator"])
        torch.set_rng_state(state["rng"])
        best_state = state["best_state"]
        result.losses = list(state["losses"])
        result.best_epoch, result.best_val_loss = state["best_epoch"], state["best_val_loss"]
        result.resumed_from, earlier = len(result.losses), float(state["wall_seconds"])
        earlier_cpu = _seconds(state.get("cpu_seconds"))
        done = state.get("finished")
        if isinstance(done, dict) and result.resumed_from >= n_epochs:
            finished = (float(done["wall_seconds"]), int(done["resumed_from"]))
            result.cpu_seconds = _seconds(done.get("cpu_seconds"))
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
    batches = PaddedBatches(batch)

    def cpu_so_far() -> float | None:
        return None if earlier_cpu is None else earlier_cpu + time.process_time() - cpu_start

    def resumable(wall_seconds: float) -> dict[str, Any]:
        """What the next epoch depends on (``CHECKPOINT_KEYS``), as a checkpoint holds it."""
        return {
            "model": model.state_dict(),
            "optimiser": optimiser.state_dict(),
            "generator": generator.get_state(),
            "rng": torch.get_rng_state(),
            "best_state": best_state,
            "losses": result.losses,
            "best_epoch": result.best_epoch,
            "best_val_loss": result.best_val_loss,
            "wall_seconds": wall_seconds,
            "cpu_seconds": cpu_so_far(),
        }

    for epoch in bar:
        model.train()
        order = torch.randperm(len(x_train), generator=generator)
        total = 0.0
        for index, mask, count, size in batches.of(order):
            loss = step_loss(index, mask, count)
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            update()
            total += loss.item() * size
        model.eval()
        with torch.no_grad():
            val_loss = float(torch.mean((model(x_val) - y_val) ** 2))
        train_loss = total / len(order)
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
            checkpoint.save(resumable(earlier + now - start))
            saved = time.perf_counter()
    if best_state is not None:
        model.load_state_dict(best_state)
    model.eval()
    if finished is not None:  # a finished training read back: its own record, unchanged
        result.wall_seconds, result.resumed_from = finished
        result.rewritten = True
        return result
    result.wall_seconds = earlier + time.perf_counter() - start
    result.cpu_seconds = cpu_so_far()
    if checkpoint is not None:  # kept: a rerun after a crash rewrites the outputs from it
        finished_record = {
            "wall_seconds": result.wall_seconds,
            "cpu_seconds": result.cpu_seconds,
            "resumed_from": result.resumed_from,
        }
        checkpoint.save({**resumable(result.wall_seconds), "finished": finished_record})
    return result


def _seconds(value: object) -> float | None:
    """A checkpoint's recorded seconds, None where an older checkpoint has none."""
    return float(value) if isinstance(value, (int, float)) else None


class AdamStep:
    """``optimiser.step()`` of a fused Adam on the CPU without its per-step Python bookkeeping.

    ``Optimizer.step`` re-groups the parameters by device and type, looks their state up and
    runs its hooks and profiling scopes on every call (its cost: docs/design.md). This calls
    the same two operations (``_foreach_add_`` of the step counts, then ``_fused_adam_``) with
    the same arguments, so
    the update is the same bit for bit (tests/test_training.py); the state stays the
    optimiser's own, so its ``state_dict`` (the resumable checkpoint) is unchanged. It falls
    back to ``optimiser.step()`` whenever it is not that case: another optimiser or options,
    no state yet (the first step creates it), a parameter without a gradient.

    A gradient laid out otherwise than its parameter (``torch.autograd.grad`` returns the GRU's
    weight gradients transposed) is first copied into its parameter's layout: PyTorch 2.13's
    fused Adam on the CPU, through ``optimiser.step()`` too, reads every gradient in memory
    order and so updates each element with another element's gradient, without an error.
    ``backward()`` lays the gradients out as their parameters (what the training passes), so
    there this changes nothing."""

    def __init__(self, optimiser: torch.optim.Optimizer) -> None:
        self.optimiser = optimiser
        groups = optimiser.param_groups
        group = groups[0]
        self._fast = (
            type(optimiser) is torch.optim.Adam
            and len(groups) == 1
            and bool(group.get("fused"))
            and not group["amsgrad"]
            and not group["maximize"]
            and not group["capturable"]
            and not group["differentiable"]
            and not group.get("decoupled_weight_decay", False)
            and not isinstance(group["lr"], torch.Tensor)
            and all(p.device.type == "cpu" and p.dtype == torch.float32 for p in group["params"])
        )

    def __call__(self) -> None:
        group = self.optimiser.param_groups[0]
        params: list[torch.Tensor] = group["params"]
        state = self.optimiser.state
        for p in params:
            if p.grad is not None and p.grad.stride() != p.stride():
                p.grad = torch.empty_like(p).copy_(p.grad)
        grads = [p.grad for p in params]
        if not self._fast or any(g is None for g in grads) or any(p not in state for p in params):
            self.optimiser.step()
            return
        states = [state[p] for p in params]
        steps = [s["step"] for s in states]
        beta1, beta2 = group["betas"]
        with torch.no_grad():
            torch._foreach_add_(steps, 1)
            torch._fused_adam_(
                params,
                grads,  # type: ignore[arg-type]
                [s["exp_avg"] for s in states],
                [s["exp_avg_sq"] for s in states],
                [],
                steps,
                amsgrad=False,
                lr=float(group["lr"]),
                beta1=float(beta1),
                beta2=float(beta2),
                weight_decay=float(group["weight_decay"]),
                eps=float(group["eps"]),
                maximize=False,
            )


class PaddedBatches:
    """An epoch's batches in the recipe's order (consecutive slices of ``batch`` windows of the
    shuffled order, the last one shorter), each padded to ``batch`` rows.

    Why padded: the compiled step has static shapes, so a shorter last batch would compile a
    second graph (as long to compile as the first). The padding repeats the batch's first
    window with mask 0, so those rows add nothing to the loss or the gradient and the step is
    the recipe's: the mean over the batch's real rows."""

    def __init__(self, batch: int) -> None:
        self.batch = batch
        self._masks: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}

    def _mask(self, size: int) -> tuple[torch.Tensor, torch.Tensor]:
        if size not in self._masks:
            mask = torch.zeros(self.batch, dtype=torch.float64)
            mask[:size] = 1.0
            self._masks[size] = (mask, torch.tensor(float(size), dtype=torch.float64))
        return self._masks[size]

    def of(
        self, order: torch.Tensor
    ) -> Iterator[tuple[torch.Tensor, torch.Tensor, torch.Tensor, int]]:
        """(window indices, mask, count of real rows as a tensor, that count) per batch."""
        for first in range(0, len(order), self.batch):
            index = order[first : first + self.batch]
            size = len(index)
            if size < self.batch:
                index = torch.cat([index, index[:1].expand(self.batch - size)])
            yield (index, *self._mask(size), size)


def batch_loss(
    model: LearnedModel, windows: torch.Tensor, labels: torch.Tensor
) -> Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]:
    """The training step's loss of a padded batch: the MSE of the next [vx, vy, ω] over its
    real rows (``mask`` 1). The batch is gathered from the whole training set inside the
    function, so that a compiled step fuses the gather with the scaling and its backward holds
    the loss too (no eager indexing, MSE and their autograd nodes per step); the GRU runs
    stage by stage (``gru_stages``)."""

    def loss(index: torch.Tensor, mask: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
        error = model(windows[index], stages=True) - labels[index]
        return (mask[:, None] * error**2).sum() / (3.0 * count)

    return loss


def training_loss(
    model: LearnedModel,
    windows: torch.Tensor,
    labels: torch.Tensor,
    settings: TrainingCompile | None,
) -> Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]:
    """``batch_loss`` as it is, or (``enabled``) compiled by ``torch.compile``.

    Why compiled: eager PyTorch runs the network as hundreds of small operations, each with
    its dispatch and autograd overhead, so a step costs the overhead, not the arithmetic; the
    compiled graph fuses them (``benchmarks/training_step.py`` measures it). Dynamo traces
    through ``nn.GRU``'s parameters only with ``allow_rnn``. The graph is static: one batch
    size (``PaddedBatches``), so one compile. ``cpp_wrapper``: Inductor's C++ wrapper calls the
    kernels from C++ instead of Python (the same kernels, so the same numbers; less overhead
    per step, and the two graphs compile as two C++ files instead of one per kernel).
    Validation stays eager (``nn.GRU``). Inductor's cache lives under ``cache`` (kept between
    runs, so a rerun compiles in seconds)."""
    loss = batch_loss(model, windows, labels)
    if settings is None or not settings.enabled:
        return loss
    import torch._dynamo

    if settings.cache:
        os.environ["TORCHINDUCTOR_CACHE_DIR"] = str(Path(settings.cache).resolve())
    try:  # before any tracing: a missing compiler fails in a moment, not after the codegen
        from torch._inductor.cpp_builder import get_cpp_compiler

        get_cpp_compiler()
    except Exception as error:  # Inductor's own exception types are private
        raise _compile_error(error, missing_compiler=True) from error
    torch._dynamo.config.allow_rnn = True
    options = {"cpp_wrapper": settings.cpp_wrapper}
    compiled = torch.compile(loss, dynamic=False, options=options)
    checked: set[int] = set()

    def step(index: torch.Tensor, mask: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
        if len(index) in checked:
            return compiled(index, mask, count)
        try:  # a new shape: this call compiles
            out = compiled(index, mask, count)
        except Exception as error:  # Inductor raises many kinds; one fix
            raise _compile_error(error) from error
        checked.add(len(index))
        return out

    return step


def _compile_error(error: Exception, missing_compiler: bool = False) -> CapeError:
    """The fix for a training step that would not compile: a missing C++ compiler (found
    before any tracing), or a compilation that failed with one present, where the usual
    cause is an ISA forced by hand that Inductor cannot generate code for."""
    first = str(error).strip().splitlines()[0][:300] if str(error).strip() else ""
    if missing_compiler:
        cause = "It needs a C++ compiler (g++ or clang++, or $CXX); install one"
    else:
        isa = os.environ.get("ATEN_CPU_CAPABILITY")
        cause = (
            f"ATEN_CPU_CAPABILITY={isa} is set: Inductor cannot compile for it; unset it, or "
            "pin `training.kernels.aten_capability: avx2` (or avx512) instead"
            if isa
            else "A C++ compiler was found, so see the error above"
        )
    return CapeError(
        f"training.compile: PyTorch could not compile the training step "
        f"({type(error).__name__}: {first}). {cause}, or set `training.compile.enabled: false` "
        "in config/config.yaml to train eagerly (the same recipe, slower)."
    )
