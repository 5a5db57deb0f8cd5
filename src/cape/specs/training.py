"""What one training reads: the model's entry (its recipe), the seed, the data's split and
sampling time, and how the training runs (threads, fused Adam, compilation, kernels)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from cape.config import section
from cape.errors import CapeError


@dataclass(frozen=True)
class TrainingSpec:
    """One training of ``model`` (SPEC §4); the seed is ``training.seed`` unless the command
    overrides it."""

    model: str
    entry: Mapping[str, Any]
    """The model's config entry: its structure and its recipe (``train``)."""
    ts: float
    split: Mapping[str, Any]
    """``data.split``: the validation split of the windows (``seed``, ``train_fraction``)."""
    seed: int
    threads: int
    fused_adam: bool
    compile: Mapping[str, Any] | None
    kernels: Mapping[str, Any] | None
    checkpoint_every: float

    @classmethod
    def from_config(cls, config: Mapping[str, Any], model: str) -> TrainingSpec:
        models = section(config, "models")
        if model not in models:
            known = ", ".join(sorted(models))
            raise CapeError(f"--model {model}: not in the config's `models` ({known})")
        data, training = section(config, "data"), section(config, "training")
        return cls(
            model=model,
            entry=models[model],
            ts=float(data["ts"]),
            split=data["split"],
            seed=int(training["seed"]),
            threads=int(training["threads"]),
            fused_adam=bool(training.get("fused_adam", True)),
            compile=training.get("compile"),
            kernels=training.get("kernels"),
            checkpoint_every=float(training.get("checkpoint_every", 60.0)),
        )
