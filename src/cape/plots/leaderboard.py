"""Figure 14: beside table 9, each model's effect against the reference model on the primary
metric, with its 95 % interval (over the training draws; over the seeds with one draw), one
panel per study (cape.study.claims.leaderboard computes them)."""

from __future__ import annotations

from collections.abc import Mapping

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from cape.plots.study import model_colour, model_label
from cape.plots.style import nothing_to_draw  # also the headless backend


def leaderboard_effects(
    tables: Mapping[str, pd.DataFrame],
    reference: str,
    metric: str,
    models: Mapping[str, Mapping],
) -> plt.Figure:
    """One panel per study (``tables``: study title → its table 9): a row per model other than
    the reference, its effect on ``metric`` against ``reference`` as a point with its interval,
    and zero, the line the verdict is read against."""
    shown = {
        title: table[table["model"] != reference].dropna(subset=["effect vs reference"])
        for title, table in tables.items()
        if len(table)
    }
    shown = {title: table for title, table in shown.items() if len(table)}
    if not shown:
        return nothing_to_draw("no model has an effect against the reference in this target")
    rows = max(len(t) for t in shown.values())
    fig, axes = plt.subplots(
        1, len(shown), figsize=(5.2 * len(shown), 1.2 + 0.55 * rows), squeeze=False
    )
    for ax, (title, table) in zip(axes[0], shown.items(), strict=True):
        y = np.arange(len(table))[::-1]
        for yi, (_, row) in zip(y, table.iterrows(), strict=True):
            effect = float(row["effect vs reference"])
            low, high = float(row["ci95_low"]), float(row["ci95_high"])
            colour = model_colour(models, str(row["model"]))
            ax.plot([low, high], [yi, yi], color=colour, lw=3, solid_capstyle="butt")
            ax.plot(effect, yi, "o", color=colour, ms=6)
        ax.axvline(0.0, color="0.3", lw=0.8, ls="--")
        ax.set_ylim(-0.6, len(table) - 0.4)
        ax.set_yticks(y, [model_label(models, str(m)) for m in table["model"]])
        ax.set_xlabel(f"{metric}\nminus {model_label(models, reference)}'s")
        ax.set_title(title, fontsize=10)
        ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    return fig
