"""Model inputs: history windows, the seeded train/validation split, feature scaling (SPEC §3).

Window i holds rows k = i … i+H−1 of ``[vx, vy, ω, T_fb, δ_fb, ΔT, Δδ]``, where the first five
are ``dstates[3:8, k]`` (the feedback inputs are those applied at step k−1) and
``Δu_k = u_k − u_{k−1}`` with ``u_{−1} = 0``; the label is ``dstates[3:6, i+H]``. A model's
physics step therefore applies ``fb + Δ`` of the last row, which is ``u_{i+H−1}``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

FEATURES = ("vx", "vy", "omega", "T_fb", "delta_fb", "dT", "ddelta")


@dataclass(frozen=True)
class WindowSet:
    """``features`` (n, H, 7) and ``labels`` (n, 3) of one data set."""

    features: np.ndarray
    labels: np.ndarray

    @property
    def history(self) -> int:
        return int(self.features.shape[1])

    def __len__(self) -> int:
        return int(self.features.shape[0])

    def subset(self, index: np.ndarray) -> WindowSet:
        return WindowSet(self.features[index], self.labels[index])


def feature_rows(dataset: dict[str, np.ndarray]) -> np.ndarray:
    """Every row k = 0 … n_steps−1 of ``[vx, vy, ω, T_fb, δ_fb, ΔT, Δδ]``, shape (n_steps, 7)."""
    dstates, inputs = dataset["dstates"], dataset["inputs"]
    n_steps = inputs.shape[1]
    previous = np.concatenate([np.zeros((2, 1)), inputs[:, :-1]], axis=1)
    return np.concatenate([dstates[3:8, :n_steps], inputs - previous], axis=0).T


def make_windows(dataset: dict[str, np.ndarray], history: int) -> WindowSet:
    """All windows of length ``history`` of a ``DYN-PP`` set (1000 − H of them for 1000 steps)."""
    rows = feature_rows(dataset)
    n_steps = rows.shape[0]
    if not 1 <= history < n_steps:
        raise ValueError(f"history length H must be in 1 … {n_steps - 1}, got {history}")
    count = n_steps - history
    index = np.arange(count)[:, None] + np.arange(history)[None, :]
    features = rows[index]  # (count, H, 7)
    labels = dataset["dstates"][3:6, history : history + count].T.copy()
    return WindowSet(features=features, labels=labels)


def split_indices(n: int, train_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A seeded random split of ``range(n)``: ``floor(train_fraction·n)`` training indices,
    the rest for validation, each sorted. The same seed gives the same split for every model."""
    if not 0.0 < train_fraction < 1.0:
        raise ValueError(f"train_fraction must lie strictly between 0 and 1, got {train_fraction}")
    order = np.random.default_rng(seed).permutation(n)
    n_train = int(np.floor(train_fraction * n))
    return np.sort(order[:n_train]), np.sort(order[n_train:])


@dataclass(frozen=True)
class StandardScaler:
    """Per-feature standardisation, fitted on the training windows only."""

    mean: np.ndarray
    scale: np.ndarray

    @classmethod
    def fit(cls, features: np.ndarray) -> StandardScaler:
        """Mean and standard deviation of each feature over all windows and rows.

        A constant feature gets scale 1, so it is centred but never divided by zero.
        """
        flat = features.reshape(-1, features.shape[-1])
        mean = flat.mean(axis=0)
        std = flat.std(axis=0)
        return cls(mean=mean, scale=np.where(std > 0, std, 1.0))

    def transform(self, features: np.ndarray) -> np.ndarray:
        return (features - self.mean) / self.scale

    def inverse_transform(self, scaled: np.ndarray) -> np.ndarray:
        return scaled * self.scale + self.mean

    def to_dict(self) -> dict[str, Any]:
        return {"mean": self.mean.tolist(), "scale": self.scale.tolist()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> StandardScaler:
        return cls(
            mean=np.asarray(data["mean"], dtype=float), scale=np.asarray(data["scale"], dtype=float)
        )
