"""Figure 15: the ground-truth question through its looks: each row's interval at each look
(the difference's repeated interval, thin; the equivalence interval, thick) against zero and
its ±margin, and the decision where it stopped (cape.study.question.report.looks_frame)."""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import pandas as pd

from cape.plots.style import nothing_to_draw  # also the headless backend

COLOURS = {
    "holds": "#2ca02c",
    "contradicted": "#d62728",
    "equivalent": "#1f77b4",
    "inconclusive": "#7f7f7f",
    "inconclusive (futile)": "#c7c7c7",
    "open": "#bcbd22",
}


def question_looks(looks: pd.DataFrame) -> plt.Figure:
    """One panel per claim; per comparison one line per look (draws per model beside it), the
    decision's colour at the look that made it, zero dashed and the margin dotted."""
    looks = looks.dropna(subset=["estimate"]) if len(looks) else looks
    if looks.empty:
        return nothing_to_draw("no look of the question has values yet (run `cape question`)")
    claims = list(dict.fromkeys(looks["claim"]))
    heights = [max(1, len(looks[looks["claim"] == c])) for c in claims]
    fig, axes = plt.subplots(
        len(claims),
        1,
        figsize=(9, 1.2 + 0.32 * sum(heights)),
        gridspec_kw={"height_ratios": heights},
        squeeze=False,
    )
    for ax, claim in zip(axes[:, 0], claims, strict=True):
        rows = looks[looks["claim"] == claim].reset_index(drop=True)
        labels = []
        for y, row in rows.iterrows():
            colour = COLOURS.get(str(row["decision"]), "black")
            finite = math.isfinite(row["low"]) and math.isfinite(row["high"])
            if finite:
                ax.plot([row["low"], row["high"]], [y, y], color=colour, lw=1)
            if math.isfinite(row["equivalence_low"]) and math.isfinite(row["equivalence_high"]):
                ax.plot([row["equivalence_low"], row["equivalence_high"]], [y, y],
                        color=colour, lw=4, alpha=0.6, solid_capstyle="butt")  # fmt: skip
            ax.plot(row["estimate"], y, "o", color=colour, ms=4)
            labels.append(f"{row['comparison']}, {int(row['draws'])} draws: {row['decision']}")
        margin = rows["margin"].dropna()
        reach = 0.0
        if len(margin):
            reach = 2 * float(margin.iloc[0])
            for sign in (-1, 1):
                ax.axvline(sign * float(margin.iloc[0]), color="black", ls=":", lw=0.8)
        last = rows.groupby("comparison").tail(1)  # the latest looks set the scale: earlier,
        ends = last[["low", "high", "estimate"]].abs().to_numpy().ravel()  # wider ones run off
        ends = ends[[math.isfinite(v) for v in ends]]
        reach = max(reach, *(ends if len(ends) else [1.0]))
        ax.set_xlim(-1.1 * reach, 1.1 * reach)
        ax.axvline(0.0, color="black", ls="--", lw=0.8)
        ax.set_yticks(range(len(rows)), labels, fontsize=7)
        ax.set_ylim(len(rows) - 0.5, -0.5)
        ax.set_title(claim, fontsize=9, loc="left")
    axes[-1, 0].set_xlabel(
        "effect (a − b, or a vs b in %): thin the repeated interval, thick the equivalence "
        "interval; dashed zero, dotted ±margin"
    )
    fig.tight_layout()
    return fig
