"""Figures of the learned models: predicted Φ against the truth, and the training curves."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

from cape.plots.style import plt
from cape.vehicle.params import GROUND_TRUTH

UNITS = {
    "Df": "N", "Dr": "N", "Frx": "N", "Iz": "kg·m²", "Svf": "N", "Svr": "N",
    "Shf": "rad", "Shr": "rad", "h": "m", "tau_delta": "s", "tau_T": "s", "Cr0": "N",
    "Cm1": "N", "Cm2": "N·s/m", "Cr2": "N·s²/m²",
}  # fmt: skip


def truth_of(name: str, ts: float) -> float | None:
    """The data-generating value of a parameter, where one exists (no load transfer: h = 0;
    instant actuators: any τ ≤ Ts, drawn at Ts)."""
    if name == "h":
        return 0.0
    if name in ("tau_delta", "tau_T"):
        return ts
    return getattr(GROUND_TRUTH, name, None)


def plot_phi(
    phis: Mapping[str, tuple[list[str], np.ndarray]],
    time: np.ndarray,
    colors: Mapping[str, str],
    labels: Mapping[str, str],
    ts: float,
    true_frx: np.ndarray | None = None,
) -> plt.Figure:
    """One panel per parameter: each model's Φ over the windows, the ground truth dashed."""
    names: list[str] = []
    for param_names, _ in phis.values():
        names += [n for n in param_names if n not in names]
    cols = 3
    rows = int(np.ceil(len(names) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(12, 1.9 * rows), sharex=True, squeeze=False)
    for ax, name in zip(axes.flat, names, strict=False):
        for model, (param_names, phi) in phis.items():
            if name in param_names:
                ax.plot(
                    time,
                    phi[:, param_names.index(name)],
                    color=colors[model],
                    lw=0.9,
                    label=labels[model],
                )
        if name == "Frx" and true_frx is not None:
            ax.plot(time, true_frx, color="black", lw=0.8, ls="--", label="ground truth")
        else:
            truth = truth_of(name, ts)
            if truth is not None:
                ax.axhline(truth, color="black", lw=0.8, ls="--", label="ground truth")
        unit = UNITS.get(name, "–")
        ax.set_ylabel(f"{name} ({unit})", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, lw=0.3, alpha=0.5)
    for ax in axes.flat[len(names) :]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("time on ETHZMobil (s)", fontsize=8)
    handles, texts = [], []
    for ax in axes.flat:
        for h, t in zip(*ax.get_legend_handles_labels(), strict=True):
            if t not in texts:
                handles.append(h)
                texts.append(t)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.legend(handles, texts, loc="lower center", ncol=len(texts), fontsize=8, frameon=False)
    return fig


def plot_training_curves(
    losses: Mapping[str, pd.DataFrame],
    best_epochs: Mapping[str, int],
    colors: Mapping[str, str],
    labels: Mapping[str, str],
) -> plt.Figure:
    """Training and validation MSE per epoch, log scale, the kept checkpoint marked."""
    fig, axes = plt.subplots(1, len(losses), figsize=(4.2 * len(losses), 3.4), squeeze=False)
    for ax, (name, frame) in zip(axes[0], losses.items(), strict=True):
        ax.semilogy(
            frame["epoch"],
            frame["train_loss"],
            color=colors[name],
            lw=0.8,
            alpha=0.6,
            label="training",
        )
        ax.semilogy(
            frame["epoch"], frame["val_loss"], color=colors[name], lw=1.2, label="validation"
        )
        best = best_epochs[name]
        best_val = float(frame.loc[frame["epoch"] == best, "val_loss"].iloc[0])
        ax.plot([best], [best_val], "k*", ms=8, label=f"kept: epoch {best}")
        ax.set_title(labels[name])
        ax.set_xlabel("epoch")
        ax.set_ylabel("MSE of next [vx, vy, ω] (unscaled)")
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
