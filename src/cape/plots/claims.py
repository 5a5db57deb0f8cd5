"""Figure 13: each closed-loop claim's effect with its 95 % interval, per training draw (over
its seeds: one trained network) and over the draws (the model class), beside the paper's value
(cape.study.claims.scorecard.evaluate_claims computes them)."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from cape.plots.style import nothing_to_draw  # also the headless backend


def _label(scope: str) -> str:
    if scope == "pooled":
        return "over the draws (t)"
    return f"{scope}: one network"


def claim_effects(effects: pd.DataFrame) -> plt.Figure:
    """One panel per claim, one band per comparison: each draw's interval over its seeds (thin)
    and the interval over the draws (thick, black), the paper's value (a red diamond) and zero
    (the verdict's line)."""
    if effects.empty:
        return nothing_to_draw("no closed-loop claim could be evaluated on the paper's study")
    claims = list(dict.fromkeys(effects["claim"]))
    heights = [max(1, effects[effects["claim"] == c]["comparison"].nunique()) for c in claims]
    fig, axes = plt.subplots(
        len(claims),
        1,
        figsize=(9, 1.1 + 0.75 * sum(heights)),
        gridspec_kw={"height_ratios": heights},
        squeeze=False,
    )
    scopes = sorted(s for s in effects["scope"].unique() if s != "pooled")
    colours = plt.get_cmap("tab10")
    for ax, claim in zip(axes[:, 0], claims, strict=True):
        rows = effects[effects["claim"] == claim]
        comparisons = list(dict.fromkeys(rows["comparison"]))
        for y, comparison in enumerate(comparisons):
            mine = rows[rows["comparison"] == comparison]
            for k, scope in enumerate([*scopes, "pooled"]):
                one = mine[mine["scope"] == scope]
                if one.empty or not np.isfinite(one["estimate"].iloc[0]):
                    continue
                r = one.iloc[0]
                offset = 0.3 - 0.6 * k / max(1, len(scopes))
                pooled = scope == "pooled"
                ax.errorbar(
                    r["estimate"],
                    y + offset,
                    xerr=[[r["estimate"] - r["low"]], [r["high"] - r["estimate"]]],
                    fmt="s" if pooled else "o",
                    color="black" if pooled else colours(k),
                    lw=2.2 if pooled else 1.0,
                    ms=5 if pooled else 3.5,
                    capsize=2,
                    label=_label(scope) if y == 0 else None,
                )
            paper = mine["paper"].iloc[0]
            if np.isfinite(paper):
                ax.plot(paper, y, "D", color="tab:red", ms=6, label="paper" if y == 0 else None)
        ax.axvline(0.0, color="0.5", lw=0.8)
        ax.set_yticks(range(len(comparisons)), comparisons)
        ax.set_ylim(len(comparisons) - 0.5, -0.5)
        ax.set_title(claim, fontsize=9, loc="left")
        ax.grid(axis="x", alpha=0.3)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper right", ncol=len(labels), fontsize=8, frameon=False)
    axes[-1, 0].set_xlabel("effect (the claim's unit); the paper's side decides the verdict")
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    return fig
