"""Figure of one closed-loop run: the path on the track with the reference, and the signals."""

from __future__ import annotations

import numpy as np
import pandas as pd

from cape.plots.style import plt
from cape.plots.tracks import closed, draw_track
from cape.tracks.track import Track

SIGNALS = (
    ("vx", "vx (m/s)"),
    ("vy", "vy (m/s)"),
    ("omega", "ω (rad/s)"),
    ("T_applied", "T (–)"),
    ("delta_applied", "δ (rad)"),
)


def plot_rollout(
    track: Track, line_x: np.ndarray, line_y: np.ndarray, series: pd.DataFrame, title: str
) -> plt.Figure:
    fig = plt.figure(figsize=(12, 6.2))
    grid = fig.add_gridspec(len(SIGNALS), 2, width_ratios=(1.15, 1.0))
    ax = fig.add_subplot(grid[:, 0])
    draw_track(ax, track, centre=False)
    ax.plot(closed(line_x), closed(line_y), color="0.55", lw=1.0, ls="--", label="reference")
    ax.plot(series["X"], series["Y"], color="tab:blue", lw=1.3, label="car")
    if len(series):
        ax.plot(series["X"].iloc[-1], series["Y"].iloc[-1], "rx", ms=8, label="end")
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=4, frameon=False)
    for i, (key, label) in enumerate(SIGNALS):
        sub = fig.add_subplot(grid[i, 1])
        sub.plot(series["t"], series[key], color="tab:blue", lw=1.0)
        if key == "vx":
            sub.plot(
                series["t"], series["ref_v"], color="0.55", lw=0.9, ls="--", label="reference speed"
            )
            sub.legend(fontsize=7, loc="lower right")
        sub.set_ylabel(label, fontsize=8)
        sub.grid(True, lw=0.3, alpha=0.5)
        sub.tick_params(labelsize=7)
        if i < len(SIGNALS) - 1:
            sub.tick_params(labelbottom=False)
    sub.set_xlabel("time (s)")
    fig.suptitle(title)
    fig.tight_layout()
    return fig
