"""One training of a configured model, as the workflow runs it: from the config's sections and
a data set to the trained model and its record (``meta.json``, ``loss.csv``).

``run_training`` builds the training's identity (the fingerprint that keys its resumable
checkpoint), trains, and returns a ``TrainingRun``; ``cape train`` only parses its arguments,
calls it and writes what it returns. PyTorch's kernels must be pinned before this module is
imported (``cape.training.kernels.pin_before_torch``).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from cape.config import PRESENTATION_KEYS
from cape.models.base import LearnedModel
from cape.models.trained import FORMAT_VERSION
from cape.specs import as_record
from cape.specs.training import TrainingSpec
from cape.training.kernels import in_effect
from cape.training.loop import (
    TRAINING_STEP,
    Checkpointing,
    TrainingData,
    TrainingResult,
    train_model,
    training_fingerprint,
)


@dataclass
class TrainingRun:
    """A finished training: the network, its ``meta.json`` record, its loss curve as
    ``loss.csv`` text, and its resumable checkpoint (kept at the last epoch: a rerun
    rewrites the outputs from it)."""

    model: LearnedModel
    meta: dict[str, Any]
    losses_csv: str
    result: TrainingResult
    checkpoint: Path


def run_training(
    spec: TrainingSpec,
    dataset: dict[str, Any],
    data_path: Path,
    out: Path,
    *,
    seed: int | None = None,
    epochs: int | None = None,
    threads: int | None = None,
    replicate: int | None = None,
    checkpoint_every: float | None = None,
    announce: Any = print,
    data_sha256: str | None = None,
) -> TrainingRun:
    """Train ``spec``'s model on ``dataset`` (read from ``data_path``), checkpointing into
    ``out``; the options override the spec's seed, epoch count, threads and checkpoint
    interval. ``announce`` receives one line before training; ``data_sha256``, the data file's
    digest when the caller has it (``planned_identity`` took it), else it is computed."""
    name, entry = spec.model, dict(spec.entry)
    seed = int(seed if seed is not None else spec.seed)
    split = spec.split
    data = TrainingData.from_dataset(
        dataset, int(entry["history"]), float(split.train_fraction), int(split.seed)
    )
    threads = int(threads or spec.threads)
    if data_sha256 is None:
        data_sha256 = hashlib.sha256(data_path.read_bytes()).hexdigest()
    compiled = spec.compile.enabled
    kernels = in_effect(spec.kernels)
    fingerprint = _fingerprint(spec, seed, epochs, threads, data_sha256)
    every = float(spec.checkpoint_every if checkpoint_every is None else checkpoint_every)
    checkpoint = Checkpointing(out / f"checkpoint-{fingerprint[:16]}.pt", fingerprint, every)
    announce(
        f"training {name}: {len(data.train)} training / {len(data.val)} validation "
        f"windows, seed {seed}"
    )
    result = train_model(
        name,
        entry,
        data,
        ts=spec.ts,
        seed=seed,
        epochs=epochs,
        threads=threads,
        fused=spec.fused_adam,
        compile_settings=spec.compile,
        checkpoint=checkpoint,
    )
    meta = {  # in this order in meta.json
        "seed": seed,
        "training_fingerprint": fingerprint,
        "replicate": replicate,
        **_outcome(result),
        "threads": threads,
        "compiled": compiled,
        "training_step": TRAINING_STEP,
        "split": as_record(split),
        "scaler": data.scaler.to_dict(),
        "data_file": str(data_path),
        "data_sha256": data_sha256,
        "torch_version": torch.__version__,
        "kernels": kernels,  # empty: the CPU's own code paths
        "resumed_from_epoch": result.resumed_from,
    }
    rows = ["epoch,train_loss,val_loss"] + [
        f"{r['epoch']},{r['train_loss']:.17g},{r['val_loss']:.17g}" for r in result.losses
    ]
    return TrainingRun(
        result.model,
        meta,
        "\n".join(rows) + "\n",
        result,
        checkpoint.path,
    )


def training_identity(model: str, seed: int, fingerprint: str) -> str:
    """A training's identity as its folder's owner record names it: the model, the seed and
    the digest of everything else its numbers depend on (recipe, data, threads, kernels)."""
    return f"{model} seed {seed} [{fingerprint[:16]}]"


def planned_identity(
    spec: TrainingSpec,
    data_sha256: str,
    seed: int | None = None,
    epochs: int | None = None,
    threads: int | None = None,
) -> str:
    """The identity of the training ``run_training`` would do with these arguments, on the
    data file of digest ``data_sha256``."""
    seed = int(seed if seed is not None else spec.seed)
    threads = int(threads or spec.threads)
    fingerprint = _fingerprint(spec, seed, epochs, threads, data_sha256)
    return training_identity(spec.model, seed, fingerprint)


def _outcome(result: TrainingResult) -> dict[str, Any]:
    """What a training did: its epochs, its kept checkpoint, its wall time and its process CPU
    seconds over every resume (meta.json; null where a part ran before CPU was recorded)."""
    return {
        "epochs": len(result.losses),
        "best_epoch": result.best_epoch,
        "best_val_loss": result.best_val_loss,
        "wall_seconds": result.wall_seconds,
        "cpu_seconds": result.cpu_seconds,
    }


def _fingerprint(
    spec: TrainingSpec, seed: int, epochs: int | None, threads: int, data_sha256: str
) -> str:
    """The training's identity, the key of its resumable checkpoint: everything its numbers
    depend on (a checkpoint never resumes under another setting)."""
    compiled = spec.compile.enabled
    kernels = in_effect(spec.kernels)
    return training_fingerprint(
        model=spec.model,
        spec={k: v for k, v in spec.entry.items() if k not in PRESENTATION_KEYS},
        ts=spec.ts,
        seed=seed,
        epochs=int(epochs if epochs is not None else spec.entry["train"]["epochs"]),
        split=as_record(spec.split),
        data_sha256=data_sha256,
        threads=threads,
        fused=spec.fused_adam,
        compiled=compiled,
        cpp_wrapper=compiled and spec.compile.cpp_wrapper,
        step=TRAINING_STEP,
        torch=torch.__version__,
        format=FORMAT_VERSION,
        **({"kernels": kernels} if kernels else {}),
    )
