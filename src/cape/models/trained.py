"""A trained model as the closed loop sees it: its physics and its network on NumPy.

Read from a model folder's ``meta.json`` (what was trained) and ``network.npz`` (the weights
exported from ``model.pt``), without PyTorch.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from cape.errors import CapeError
from cape.layout import paths
from cape.models.physics import ModelPhysics
from cape.models.registry import build_physics
from cape.storage.io import read_csv

FORMAT_VERSION = 1
"""Version of ``meta.json``'s layout."""


class PhiPredictor(Protocol):
    def phi(self, window: np.ndarray) -> np.ndarray: ...


@dataclass
class TrainedModel:
    """Window → Φ (``network``) → one Euler step (``physics``), one window at a time."""

    physics: ModelPhysics
    network: PhiPredictor

    def phi(self, window: np.ndarray) -> np.ndarray:
        """Φ (P,) for one unscaled window (H, 7)."""
        return self.network.phi(window)

    def predict(self, window: np.ndarray) -> np.ndarray:
        """Next [vx, vy, ω] (3,) for one unscaled window (H, 7)."""
        last = window[-1]
        nxt = self.physics.step_velocities(
            last[0],
            last[1],
            last[2],
            (last[3], last[4]),
            (last[3] + last[5], last[4] + last[6]),
            self.phi(window),
        )
        return np.array(nxt, dtype=np.float64)


def _train_again(meta: Path) -> str:
    """The fix for a model folder whose files do not fit: train it again; Snakemake's --force
    replaces the training's own files. Never "delete the folder": it may be a user's (issue 61)."""
    weights = Path(meta).parent / paths.WEIGHTS
    return f"train it again (`snakemake --cores 2 --force {weights}`, which replaces its files)"


def read_meta(folder: str | Path) -> dict[str, Any]:
    """A model folder's ``meta.json``, checked for its format version."""
    path = Path(folder) / paths.META
    try:
        meta = json.loads(path.read_text())
    except FileNotFoundError:
        raise CapeError(
            f"{path}: missing; train the model first (snakemake --cores 2 {path})"
        ) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CapeError(f"{path}: corrupt ({exc}); {_train_again(path)}") from exc
    if not isinstance(meta, dict):
        raise CapeError(f"{path}: corrupt (not a JSON object); {_train_again(path)}")
    missing = [k for k in ("name", "spec", "ts") if k not in meta]
    if missing:
        raise CapeError(f"{path}: lacks {', '.join(missing)}; {_train_again(path)}")
    if meta.get("format") != FORMAT_VERSION:
        raise CapeError(
            f"{path}: checkpoint format {meta.get('format')!r}, expected {FORMAT_VERSION}; retrain"
        )
    return meta


LOSS_COLUMNS = ("epoch", "train_loss", "val_loss")


def read_training(folder: str | Path) -> tuple[Any, dict[str, Any]]:
    """A model folder's ``loss.csv`` (a DataFrame with epoch, train_loss, val_loss: one row
    per epoch, numbers) and its ``meta.json`` (``best_val_loss`` a finite number,
    ``best_epoch`` an epoch), or ``CapeError`` naming the file and the fix."""
    import pandas as pd

    folder = Path(folder)
    meta = read_meta(folder)
    path = folder / paths.LOSSES
    fix = _train_again(folder / paths.META)
    escaped = fix.replace("{", "{{").replace("}", "}}")  # a template: {reason} is filled in
    losses = read_csv(path, fix, "not a loss curve ({reason}); " + escaped)
    missing = [c for c in LOSS_COLUMNS if c not in losses]
    if missing or losses.empty:
        what = f"lacks the column(s) {', '.join(missing)}" if missing else "has no epoch"
        raise CapeError(f"{path}: {what} (expected {', '.join(LOSS_COLUMNS)}); {fix}")
    numbers = losses[list(LOSS_COLUMNS)].apply(pd.to_numeric, errors="coerce")
    if numbers.isna().any().any():
        raise CapeError(f"{path}: holds values that are not numbers; {fix}")
    best = meta.get("best_val_loss")
    if isinstance(best, bool) or not isinstance(best, int | float) or not math.isfinite(best):
        raise CapeError(
            f"{folder / paths.META}: `best_val_loss` is {best!r}, not a finite number; {fix}"
        )
    epoch = meta.get("best_epoch")
    if isinstance(epoch, bool) or not isinstance(epoch, int) or epoch < 0:
        raise CapeError(f"{folder / paths.META}: `best_epoch` is {epoch!r}, not an epoch; {fix}")
    return numbers, meta


def load_physics(
    folder: str | Path, expected_name: str | None = None, meta: dict[str, Any] | None = None
) -> ModelPhysics:
    """The physics of the model trained in ``folder`` (its name, spec and Ts from meta.json,
    or from ``meta``, that file already read)."""
    meta = meta if meta is not None else read_meta(folder)
    name = meta["name"]
    if expected_name is not None and name != expected_name:
        raise CapeError(f"{folder}: holds model {name!r}, expected {expected_name!r}")
    return build_physics(name, meta["spec"], meta["ts"])


def load_trained(
    folder: str | Path,
    expected_name: str | None = None,
    compile_settings: dict[str, Any] | None = None,
) -> TrainedModel:
    """The trained model in ``folder`` for the closed loop, or a ``CapeError`` with the fix.
    ``compile_settings`` (``rollout.compile``) runs its Φ as one compiled C function."""
    from cape.models.network import load_network

    meta = read_meta(folder)
    physics = load_physics(folder, expected_name, meta)
    weights = meta.get("weights_sha256") or ""  # the network must be exported from them
    network = load_network(Path(folder) / paths.NETWORK, compile_settings, weights)
    shape, expected = (
        (network.history, network.n_outputs),
        (
            physics.history,
            len(physics.param_names),
        ),
    )
    if shape != expected:
        raise CapeError(
            f"{Path(folder) / paths.NETWORK}: built for windows of {shape[0]} rows and "
            f"{shape[1]} parameters, the {physics.name} model of meta.json has {expected[0]} and "
            f"{expected[1]}; delete it and export it again from model.pt"
        )
    return TrainedModel(physics, network)
