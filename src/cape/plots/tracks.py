"""Figure: both tracks with their BayesRace racelines and the generated data trajectories."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cape.plots.style import plt
from cape.tracks.track import Raceline, Track


def closed(a: np.ndarray) -> np.ndarray:
    """A closed curve's coordinates with the first point repeated at the end, for drawing."""
    return np.append(a, a[:1])


def draw_track(ax: plt.Axes, track: Track, centre: bool = True) -> None:
    """Boundaries (and the dashed centre line) of ``track`` on ``ax``, equal axes in metres."""
    ax.plot(
        closed(track.inner[0]),
        closed(track.inner[1]),
        color="black",
        lw=1.2,
        label="track boundary",
    )
    ax.plot(closed(track.outer[0]), closed(track.outer[1]), color="black", lw=1.2)
    if centre:
        ax.plot(
            closed(track.center.x),
            closed(track.center.y),
            color="0.6",
            lw=0.8,
            ls="--",
            label="centre line",
        )
    ax.set_xlabel("X (m)")
    ax.set_ylabel("Y (m)")
    ax.set_aspect("equal")
    ax.grid(True, lw=0.3, alpha=0.5)


@dataclass(frozen=True)
class TrackPanel:
    track: Track
    raceline: Raceline
    dataset: dict[str, np.ndarray]


def plot_tracks(panels: list[TrackPanel]) -> plt.Figure:
    """One panel per track: boundaries, centre line, raceline, RKF and Euler trajectories."""
    fig, axes = plt.subplots(1, len(panels), figsize=(6.0 * len(panels), 5.2), squeeze=False)
    for ax, panel in zip(axes[0], panels, strict=True):
        track, rl, data = panel.track, panel.raceline, panel.dataset
        draw_track(ax, track)
        ax.plot(
            closed(rl.x),
            closed(rl.y),
            color="tab:green",
            lw=1.4,
            label=f"BayesRace raceline ({rl.name})",
        )
        states, dstates = data["states"], data["dstates"]
        ax.plot(
            states[0], states[1], color="tab:blue", lw=1.0, label="data: states (RKF, ground truth)"
        )
        ax.plot(
            dstates[0, 1:],
            dstates[1, 1:],
            color="tab:red",
            lw=0.8,
            ls=":",
            label="data: dstates (Euler labels)",
        )
        ax.plot(states[0, 0], states[1, 0], "o", color="tab:blue", ms=5, label="start")
        duration = data["time"][-1]
        ax.set_title(f"{track.name} (width {track.width:.2f} m), {duration:.0f} s of data")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=8, frameon=False)
    return fig


def plot_raceline(track: Track, line_x: np.ndarray, line_y: np.ndarray, speed: np.ndarray,
                  bayesrace: Raceline, title: str) -> plt.Figure:  # fmt: skip
    """CAPE's raceline coloured by its speed profile, beside the BayesRace raceline."""
    fig, ax = plt.subplots(figsize=(8.0, 5.6))
    draw_track(ax, track)
    ax.plot(closed(bayesrace.x), closed(bayesrace.y), color="tab:orange", lw=1.0, ls="-.",
            label=f"BayesRace raceline ({bayesrace.name})")  # fmt: skip
    points = ax.scatter(line_x, line_y, c=speed, s=2, cmap="viridis", label="CAPE raceline")
    fig.colorbar(points, ax=ax, label="path speed v_path (m/s), before scaling")
    ax.plot(line_x[0], line_y[0], "k>", ms=7, label="start")
    ax.set_title(title)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=3, fontsize=8, frameon=False)
    fig.tight_layout()
    return fig
