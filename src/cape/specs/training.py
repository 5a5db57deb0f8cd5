"""What one training reads: the model's entry (its recipe), the seed, the data's split and
sampling time, and how the training runs (threads, fused Adam, compilation, kernels); and the
settings of the checks that decide whether a training worked (``HealthSettings``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from cape.config import section, setting
from cape.specs import JSON, Entry, entry_of


@dataclass(frozen=True)
class Split:
    """``data.split``: the share of a data set's windows that trains, and the seed of the
    random split into training and validation windows."""

    train_fraction: float
    seed: int

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> Split:
        split = section(config, "data")["split"]
        return cls(split["train_fraction"], split["seed"])


@dataclass(frozen=True)
class TrainingCompile:
    """``training.compile``: the training step compiled by ``torch.compile`` (``enabled``), with
    Inductor's C++ wrapper (``cpp_wrapper``) and its cache folder (``cache``; None: PyTorch's)."""

    enabled: bool
    cpp_wrapper: bool
    cache: str | None

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> TrainingCompile:
        given = setting(section(config, "training"), "compile", "training")
        return cls(
            bool(setting(given, "enabled", "training.compile")),
            bool(setting(given, "cpp_wrapper", "training.compile")),
            setting(given, "cache", "training.compile"),
        )


@dataclass(frozen=True)
class Kernels:
    """``training.kernels``: the CPU code paths of a training's kernels, each None where the
    CPU's own is taken (cape/training/kernels.py)."""

    mkl_cbwr: str | None = None
    aten_capability: str | None = None
    inductor_simdlen: int | None = None

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> Kernels:
        given = setting(section(config, "training"), "kernels", "training")
        return cls(**{k: given.get(k) for k in ("mkl_cbwr", "aten_capability", "inductor_simdlen")})


@dataclass(frozen=True)
class RmseBar:
    """SPEC §4.2's bar: the largest ETHZ validation one-step RMSE of each state."""

    vx: float
    vy: float
    omega: float


@dataclass(frozen=True)
class Stall:
    """A stalled loss: the training loss must fall at least ``min_drop`` (relative) after epoch
    ``after``."""

    after: int
    min_drop: float


@dataclass(frozen=True)
class HealthSettings:
    """``training.health``: the models the bar applies to, the bar, the stalled loss and the
    outlier factor (cape/training/health.py); a check the section leaves out is None."""

    models: tuple[str, ...]
    val_rmse_max: RmseBar | None
    stall: Stall | None
    outlier_factor: float | None

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> HealthSettings:
        return cls.of(setting(section(config, "training"), "health", "training"))

    @classmethod
    def of(cls, health: Mapping[str, JSON]) -> HealthSettings:
        """From the ``training.health`` section itself (as a scorecard's evidence records it)."""
        bar, stall = health.get("val_rmse_max"), health.get("stall")
        return cls(
            tuple(health.get("models") or ()),
            None if bar is None else RmseBar(bar["vx"], bar["vy"], bar["omega"]),
            None if stall is None else Stall(stall["after"], stall["min_drop"]),
            health.get("outlier_factor"),
        )

    def applies_to(self, model: str) -> bool:
        """Whether SPEC §4.2's bar applies to ``model``."""
        return model in self.models


@dataclass(frozen=True)
class TrainingSettings:
    """The ``training`` section's settings every training shares, as the config spells them:
    the first training's seed (the k-th's is seed + k), threads, Adam's fused kernel and the
    seconds between resumable checkpoints."""

    seed: int
    threads: int
    fused_adam: bool
    checkpoint_every: float

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> TrainingSettings:
        training = section(config, "training")
        return cls(
            seed=training["seed"],
            threads=training["threads"],
            fused_adam=setting(training, "fused_adam", "training"),
            checkpoint_every=setting(training, "checkpoint_every", "training"),
        )


@dataclass(frozen=True)
class TrainingSpec:
    """One training of ``model`` (SPEC §4); the seed is ``training.seed`` unless the command
    overrides it."""

    model: str
    entry: Entry
    """The model's config entry: its structure and its recipe (``train``)."""
    ts: float
    split: Split
    seed: int
    threads: int
    fused_adam: bool
    compile: TrainingCompile
    kernels: Kernels
    checkpoint_every: float

    @classmethod
    def from_config(cls, config: Mapping[str, Any], model: str) -> TrainingSpec:
        entry = entry_of(section(config, "models"), model, "--model", "models")
        shared = TrainingSettings.from_config(config)
        return cls(
            model=model,
            entry=entry,
            ts=float(section(config, "data")["ts"]),
            split=Split.from_config(config),
            seed=int(shared.seed),
            threads=int(shared.threads),
            fused_adam=bool(shared.fused_adam),
            compile=TrainingCompile.from_config(config),
            kernels=Kernels.from_config(config),
            checkpoint_every=float(shared.checkpoint_every),
        )
