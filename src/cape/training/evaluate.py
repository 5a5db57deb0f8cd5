"""Open-loop evaluation, model complexity and frozen parameters (SPEC §4.4, §4.5).

Everything here is computed from trained models and data sets; the tables and figures only
format what these functions return.
"""

from __future__ import annotations

import io
import time
from typing import Any

import numpy as np
import torch

from cape.data.windows import WindowSet, feature_rows
from cape.models.base import LearnedModel
from cape.models.trained import PhiPredictor
from cape.vehicle.params import GROUND_TRUTH

STATE_NAMES = ("vx", "vy", "omega")


def predict(model: LearnedModel, features: np.ndarray) -> np.ndarray:
    """Next [vx, vy, ω] for a batch of unscaled windows (n, H, 7), with the training graph."""
    with torch.no_grad():
        return model(torch.as_tensor(features, dtype=torch.float64)).numpy()


def predict_phi(model: LearnedModel, features: np.ndarray) -> np.ndarray:
    """Φ (n, P) for a batch of windows, with the training graph."""
    with torch.no_grad():
        return model.phi(torch.as_tensor(features, dtype=torch.float64)).numpy()


def rear_slip(data: dict[str, np.ndarray]) -> np.ndarray:
    """|α_r| along a data set's training trajectory (``dstates``), with the true lr (SPEC §1):
    how far into the rear tyre's curve the data reach, which bounds what a model can learn."""
    vx, vy, omega = data["dstates"][3:6]
    return np.abs(np.arctan2(GROUND_TRUTH.lr * omega - vy, np.abs(vx)))


def one_step_rmse(model: LearnedModel, windows: WindowSet) -> dict[str, float]:
    """Root-mean-square one-step error of vx, vy, ω."""
    err = predict(model, windows.features) - windows.labels
    return {name: float(np.sqrt(np.mean(err[:, i] ** 2))) for i, name in enumerate(STATE_NAMES)}


def multistep_error(
    model: LearnedModel, dataset: dict[str, np.ndarray], horizon: int
) -> dict[str, float]:
    """Mean absolute error of vx, vy, ω after ``horizon`` steps of open-loop rollout.

    From every window whose horizon fits in the data, the model predicts the next velocities,
    which replace the measured ones in the following window (the inputs stay the recorded
    ones), ``horizon`` times; the last prediction is compared with the data.
    """
    history = model.history
    rows = feature_rows(dataset)
    starts = np.arange(0, rows.shape[0] - history - horizon + 2)
    # the rollout's windows, one per start, advanced together
    seq = np.stack([rows[s : s + history] for s in starts])
    labels = dataset["dstates"][3:6]
    for k in range(horizon):
        nxt = predict(model, seq)
        if k == horizon - 1:
            break
        new_rows = rows[starts + history + k].copy()
        new_rows[:, 0:3] = nxt
        seq = np.concatenate([seq[:, 1:], new_rows[:, None, :]], axis=1)
    target = labels[:, starts + history + horizon - 1].T
    err = np.abs(nxt - target)
    return {name: float(err[:, i].mean()) for i, name in enumerate(STATE_NAMES)}


def float32_size_mib(model: LearnedModel) -> float:
    """Size of the float32 network weights as a saved state dict, in MiB (as the paper counts)."""
    buffer = io.BytesIO()
    torch.save({k: v.detach().to(torch.float32) for k, v in model.named_parameters()}, buffer)
    return buffer.getbuffer().nbytes / 2**20


def count_flops(model: LearnedModel, window: np.ndarray) -> int:
    """FLOPs of one Φ prediction, counted by PyTorch's flop counter (matrix products)."""
    from torch.utils.flop_counter import FlopCounterMode

    counter = FlopCounterMode(display=False)
    with counter, torch.no_grad():
        model.phi(torch.as_tensor(window[None], dtype=torch.float64))
    return int(counter.get_total_flops())


def time_inference(predictor: PhiPredictor, window: np.ndarray, repeats: int) -> float:
    """Median wall time (ms) of one Φ prediction, after warm-up."""
    for _ in range(max(10, repeats // 20)):
        predictor.phi(window)
    times = np.empty(repeats)
    for i in range(repeats):
        start = time.perf_counter()
        predictor.phi(window)
        times[i] = time.perf_counter() - start
    return float(np.median(times) * 1e3)


def complexity_row(model: LearnedModel, window: np.ndarray, repeats: int) -> dict[str, Any]:
    """One row of the complexity table (SPEC §4.4)."""
    return {
        "model": model.name,
        "params_M": model.n_parameters() / 1e6,
        "size_MB": float32_size_mib(model),
        "gru_layers": model.gru_layers(),
        "fc_layers": model.fc_layers(),
        "flops_M": count_flops(model, window) / 1e6,
        "inference_ms": time_inference(model.inference(), window, repeats),
    }


def frozen_parameters(model: LearnedModel, train_windows: WindowSet) -> dict[str, float]:
    """Per-component median of Φ over the training windows (SPEC §4.5).

    A model without a drivetrain law (DPM predicts Frx) gets the ground-truth Cm1, Cm2, Cr0,
    Cr2 instead, since a frozen force would not respond to the throttle.
    """
    phi = predict_phi(model, train_windows.features)
    frozen = {name: float(np.median(phi[:, i])) for i, name in enumerate(model.param_names)}
    if "Frx" in frozen:
        frozen.pop("Frx")
        for name in ("Cm1", "Cm2", "Cr0", "Cr2"):
            frozen[name] = getattr(GROUND_TRUTH, name)
    return frozen
