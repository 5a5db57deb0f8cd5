"""One training of a configured model, as the workflow runs it: from the config's sections and
a data set to the trained model and its record (``meta.json``, ``loss.csv``).

``run_training`` builds the training's identity (the fingerprint that keys its resumable
checkpoint), trains, and returns a ``TrainingRun``; ``cape train`` only parses its arguments,
calls it and writes what it returns. PyTorch's kernels must be pinned before this module is
imported (``cape.models.kernels.pin_before_torch``).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from cape.config import PRESENTATION_KEYS
from cape.models.base import LearnedModel
from cape.models.kernels import in_effect
from cape.models.trained import FORMAT_VERSION
from cape.models.training import (
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
    ``loss.csv`` text, and where its resumable checkpoint was (deleted once the model is
    saved)."""

    model: LearnedModel
    meta: dict[str, Any]
    losses_csv: str
    result: TrainingResult
    checkpoint: Path


def run_training(
    name: str,
    spec: dict[str, Any],
    data_section: dict[str, Any],
    training_section: dict[str, Any],
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
) -> TrainingRun:
    """Train model ``name`` (its config entry ``spec``) on ``dataset`` (read from
    ``data_path``), checkpointing into ``out``; the options override the config's seed, epoch
    count, threads and checkpoint interval. ``announce`` receives one line before training."""
    seed = int(seed if seed is not None else training_section["seed"])
    split = data_section["split"]
    data = TrainingData.from_dataset(
        dataset, int(spec["history"]), float(split["train_fraction"]), int(split["seed"])
    )
    threads = int(threads or training_section["threads"])
    data_sha256 = hashlib.sha256(data_path.read_bytes()).hexdigest()
    fused = bool(training_section.get("fused_adam", True))
    compiled = bool((training_section.get("compile") or {}).get("enabled", False))
    kernels = in_effect(training_section.get("kernels"))
    fingerprint = _fingerprint(
        name, spec, data_section, training_section, seed, epochs, threads, data_sha256
    )
    every = training_section.get("checkpoint_every", 60.0)
    every = float(every if checkpoint_every is None else checkpoint_every)
    checkpoint = Checkpointing(out / f"checkpoint-{fingerprint[:16]}.pt", fingerprint, every)
    announce(
        f"training {name}: {len(data.train)} training / {len(data.val)} validation "
        f"windows, seed {seed}"
    )
    result = train_model(
        name,
        spec,
        data,
        ts=float(data_section["ts"]),
        seed=seed,
        epochs=epochs,
        threads=threads,
        fused=fused,
        compile_settings=training_section.get("compile"),
        checkpoint=checkpoint,
    )
    meta = {  # in this order in meta.json
        "seed": seed,
        "replicate": replicate,
        **_outcome(result),
        "threads": threads,
        "compiled": compiled,
        "training_step": TRAINING_STEP,
        "split": split,
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


def _outcome(result: TrainingResult) -> dict[str, Any]:
    """What a training did: its epochs, its kept checkpoint and its wall time (meta.json)."""
    return {
        "epochs": len(result.losses),
        "best_epoch": result.best_epoch,
        "best_val_loss": result.best_val_loss,
        "wall_seconds": result.wall_seconds,
    }


def _fingerprint(
    name: str,
    spec: dict[str, Any],
    data_section: dict[str, Any],
    training_section: dict[str, Any],
    seed: int,
    epochs: int | None,
    threads: int,
    data_sha256: str,
) -> str:
    """The training's identity, the key of its resumable checkpoint: everything its numbers
    depend on (a checkpoint never resumes under another setting)."""
    compile_cfg = training_section.get("compile") or {}
    compiled = bool(compile_cfg.get("enabled", False))
    kernels = in_effect(training_section.get("kernels"))
    return training_fingerprint(
        model=name,
        spec={k: v for k, v in spec.items() if k not in PRESENTATION_KEYS},
        ts=float(data_section["ts"]),
        seed=seed,
        epochs=int(epochs if epochs is not None else spec["train"]["epochs"]),
        split=data_section["split"],
        data_sha256=data_sha256,
        threads=threads,
        fused=bool(training_section.get("fused_adam", True)),
        compiled=compiled,
        cpp_wrapper=compiled and bool(compile_cfg.get("cpp_wrapper", False)),
        step=TRAINING_STEP,
        torch=torch.__version__,
        format=FORMAT_VERSION,
        **({"kernels": kernels} if kernels else {}),
    )
