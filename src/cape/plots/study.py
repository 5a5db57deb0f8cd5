"""The study's figures (SPEC §9): sweeps over η with confidence bands, bars with CIs, time
series and trajectories of chosen runs, the closed-loop block diagram. Every function takes
data frames and returns a figure; the notebooks only choose what to draw and save it."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from cape.closedloop.disturbances import STAGES, source_class, source_entries
from cape.closedloop.rollout import FAILURES
from cape.layout.names import PlantName
from cape.plots.style import plt
from cape.plots.tracks import closed, draw_track
from cape.specs.run import DisturbancesSpec
from cape.tracks.geometry import ClosedPath
from cape.tracks.track import Track

CONTROLLER_STYLES = ("-", "--", "-.", ":", (0, (5, 1, 1, 1)))
MARKERS = ("o", "s", "^", "D", "v", "P", "X")


def model_colour(models: Mapping[str, Mapping], name: str) -> str:
    base = PlantName.parse(name).model or name
    return str(models.get(base, {}).get("color", "0.3"))


def model_label(models: Mapping[str, Mapping], name: str) -> str:
    plant = PlantName.parse(name)
    if plant.is_truth:
        return "true model"
    base = str(plant.model)
    label = str(models.get(base, {}).get("label", base.upper()))
    return f"{label} (fixed)" if plant.kind == "fixed" else label


def interval(cells: pd.DataFrame, metric: str) -> tuple[np.ndarray, np.ndarray]:
    """Each cell's 95 % CI of ``metric``: within the metric's range when the summary has it
    (``_lo``, ``_hi``), else mean ± half-width; a single run's cell collapses to its mean."""
    mean = cells[f"{metric}_mean"].to_numpy(dtype=float)
    if f"{metric}_lo" in cells:
        low = cells[f"{metric}_lo"].to_numpy(dtype=float)
        high = cells[f"{metric}_hi"].to_numpy(dtype=float)
    else:
        half = np.nan_to_num(cells[f"{metric}_ci"].to_numpy(dtype=float))
        low, high = mean - half, mean + half
    return np.where(np.isnan(low), mean, low), np.where(np.isnan(high), mean, high)


def eta_sweep(
    summary: pd.DataFrame,
    metrics: Sequence[tuple[str, str]],
    controllers: Mapping[str, str],
    models: Mapping[str, Mapping],
) -> plt.Figure:
    """Rows: metrics (column prefix, axis label); columns: controllers; a line per model with
    its 95 % confidence band over seeds."""
    names = [c for c in controllers if c in set(summary["controller"])]
    fig, axes = plt.subplots(
        len(metrics), len(names), figsize=(3.0 * len(names), 2.6 * len(metrics)),
        sharex=True, squeeze=False,
    )  # fmt: skip
    for j, controller in enumerate(names):
        cells = summary[summary["controller"] == controller]
        for i, (metric, ylabel) in enumerate(metrics):
            ax = axes[i, j]
            for k, (model, group) in enumerate(cells.groupby("model", sort=True)):
                group = group.sort_values("eta")
                mean = group[f"{metric}_mean"].to_numpy(dtype=float)
                low, high = interval(group, metric)
                colour = model_colour(models, model)
                ax.plot(group["eta"], mean, color=colour, marker=MARKERS[k % len(MARKERS)],
                        ms=3, lw=1.2, label=model_label(models, model))  # fmt: skip
                ax.fill_between(group["eta"], low, high, color=colour, alpha=0.18)
            ax.grid(True, lw=0.3, alpha=0.5)
            if j == 0:
                ax.set_ylabel(ylabel)
            if i == 0:
                ax.set_title(controllers[controller])
            if i == len(metrics) - 1:
                ax.set_xlabel("η (disturbance level)")
    # every panel's models: PID's panel has only the plant, an NMPC's the internal models
    handles, labels = legend_entries(axes.ravel())
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), frameon=False,
               bbox_to_anchor=(0.5, -0.02))  # fmt: skip
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return fig


def legend_entries(axes: Sequence[plt.Axes]) -> tuple[list, list[str]]:
    """The distinct labelled artists of several panels, in order of first appearance."""
    seen: dict[str, object] = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            seen.setdefault(label, handle)
    return list(seen.values()), list(seen)


def bars(
    summary: pd.DataFrame,
    metrics: Sequence[tuple[str, str]],
    controllers: Mapping[str, str],
    models: Mapping[str, Mapping],
    order: Sequence[str] | None = None,
) -> plt.Figure:
    """Grouped bars, one panel per metric: per controller, one bar per model, the mean over the
    η grid of the per-η means, with the root-mean-square of their 95 % CIs as error bar (kept
    within the cells' bounded intervals, so that it never crosses a value no run can take)."""
    fig, axes = plt.subplots(
        len(metrics), 1, figsize=(max(7.0, 1.6 + 1.5 * len(controllers)), 3.0 * len(metrics)),
        squeeze=False,
    )  # fmt: skip
    for ax, (metric, ylabel) in zip(axes[:, 0], metrics, strict=True):
        _bar_panel(ax, summary, metric, ylabel, controllers, models, order)
    # one legend for every panel, above them, so that it never covers a panel's tick labels
    handles, labels = legend_entries(axes[:, 0])
    found = dict(zip(labels, handles, strict=True))
    wanted = [model_label(models, m) for m in order or sorted(set(summary["model"]))]
    labels = [label for label in wanted if label in found]  # the models' order, not the bars'
    handles = [found[label] for label in labels]
    ncol = max(1, min(len(labels), int(fig.get_figwidth() // 2.6)))  # ≈2.6 in per entry
    fig.legend(handles, labels, fontsize=8, ncol=ncol, frameon=False, loc="upper center")
    rows = -(-max(len(labels), 1) // ncol)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.22 * rows / fig.get_figheight() - 0.02))
    return fig


def _bar_panel(
    ax: plt.Axes,
    summary: pd.DataFrame,
    metric: str,
    ylabel: str,
    controllers: Mapping[str, str],
    models: Mapping[str, Mapping],
    order: Sequence[str] | None,
) -> None:
    names = [c for c in controllers if c in set(summary["controller"])]
    model_names = list(order or sorted(set(summary["model"])))
    width = 0.8 / max(len(model_names), 1)
    labelled: set[str] = set()
    for i, controller in enumerate(names):
        # the models this controller has, centred on its tick (PID in the ground-truth study
        # has only the true model: one bar on the tick, not the last of four slots)
        bars = [b for b in (_bar(summary, controller, model, metric) for model in model_names) if b]
        for k, (model, mean, below, above) in enumerate(bars):
            label = "_nolegend_" if model in labelled else model_label(models, model)
            fixed = PlantName.parse(model).kind == "fixed"
            ax.bar(i + (k - (len(bars) - 1) / 2) * width, mean, width, yerr=[[below], [above]],
                   capsize=2, color=model_colour(models, model),
                   alpha=0.5 if fixed else 0.95, hatch="//" if fixed else None,
                   edgecolor="black", lw=0.5,
                   label=label)  # fmt: skip
            labelled.add(model)
    ax.set_xticks(np.arange(len(names)), [controllers[c] for c in names], fontsize=8)
    ax.set_ylabel(ylabel)
    ax.grid(True, axis="y", lw=0.3, alpha=0.5)


def _bar(
    summary: pd.DataFrame, controller: str, model: str, metric: str
) -> tuple[str, float, float, float] | None:
    """(model, mean over the η grid, error below, error above), or None without data."""
    cells = summary[(summary["controller"] == controller) & (summary["model"] == model)]
    if not len(cells) or cells[f"{metric}_mean"].isna().all():
        return None
    mean = float(cells[f"{metric}_mean"].mean())
    half = float(np.nan_to_num(cells[f"{metric}_ci"].pow(2).mean() ** 0.5))
    low, high = interval(cells, metric)
    below = mean - max(mean - half, float(np.nanmin(low)))
    above = min(mean + half, float(np.nanmax(high))) - mean
    return model, mean, below, above


def robust_limits(values: np.ndarray, tail: float = 0.005) -> tuple[float, float] | None:
    """Axis limits that show the signals rather than the last samples of a run whose plant
    diverged as it failed (ω of −100 rad/s would flatten every other trace): the range of the
    central 99 % of the samples padded by a tenth of it, when the whole range is more than
    twice that; None (Matplotlib's own limits) otherwise."""
    finite = np.asarray(values, dtype=float)
    finite = finite[np.isfinite(finite)]
    if finite.size == 0:
        return None
    low, high = (float(q) for q in np.quantile(finite, [tail, 1.0 - tail]))
    span = max(high - low, 1e-9)
    if finite.max() - finite.min() <= 2.0 * span:
        return None
    return low - 0.1 * span, high + 0.1 * span


def signals_grid(
    series: Mapping[tuple[str, str], pd.DataFrame],
    signals: Sequence[tuple[str, str]],
    controllers: Mapping[str, str],
    models: Mapping[str, Mapping],
) -> plt.Figure:
    """Rows: signals; columns: models; a line per controller (one run each)."""
    model_names = sorted({m for m, _ in series})
    height = max(3.4, 1.6 * len(signals) + 0.9)
    fig, axes = plt.subplots(
        len(signals), len(model_names), figsize=(4.2 * len(model_names), height),
        sharex=True, squeeze=False,
    )  # fmt: skip
    for j, model in enumerate(model_names):
        for c, controller in enumerate(controllers):
            frame = series.get((model, controller))
            if frame is None:
                continue
            for i, (key, _) in enumerate(signals):
                axes[i, j].plot(frame["t"], frame[key], lw=0.9, color=f"C{c % 10}",
                                ls=CONTROLLER_STYLES[c % len(CONTROLLER_STYLES)],
                                label=controllers[controller])  # fmt: skip
        axes[0, j].set_title(model_label(models, model))
        axes[-1, j].set_xlabel("time (s)")
        for i, (key, ylabel) in enumerate(signals):
            values = [series[(model, c)][key] for c in controllers if (model, c) in series]
            limits = robust_limits(np.concatenate(values)) if values else None
            if limits is not None:
                axes[i, j].set_ylim(*limits)
            axes[i, j].grid(True, lw=0.3, alpha=0.5)
            if j == 0:
                axes[i, j].set_ylabel(ylabel)
    # a controller may be missing from a column (PID has no internal model)
    handles, labels = legend_entries(axes[0])
    seen = dict(zip(labels, handles, strict=True))
    order = [label for label in controllers.values() if label in seen]
    fig.legend([seen[k] for k in order], order, loc="lower center", ncol=len(seen),
               frameon=False, bbox_to_anchor=(0.5, 0.0))  # fmt: skip
    fig.tight_layout(rect=(0, 0.5 / height, 1, 1))
    return fig


def trajectories(
    track: Track,
    reference: tuple[np.ndarray, np.ndarray],
    paths: Mapping[str, Mapping[str, pd.DataFrame]],
    labels: Mapping[str, str],
    titles: Mapping[str, str],
    styles: Mapping[str, object] | None = None,
    colours: Mapping[str, str] | None = None,
    ncols: int = 4,
) -> plt.Figure:
    """One panel per key of ``paths``, each with its named runs' paths on the track; every
    path ends in a cross (where the lap ended or the car left the track)."""
    cols = min(ncols, len(paths))
    rows = -(-len(paths) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.0 * cols, 4.8 * rows), squeeze=False)
    for ax in axes.ravel()[len(paths) :]:
        ax.axis("off")
    for ax, (panel, runs) in zip(axes.ravel(), paths.items(), strict=False):
        draw_track(ax, track, centre=False)
        ax.plot(closed(reference[0]), closed(reference[1]), color="0.6", lw=0.8, ls=":",
                label="reference")  # fmt: skip
        for c, (name, frame) in enumerate(runs.items()):
            style = (styles or {}).get(name, CONTROLLER_STYLES[c % len(CONTROLLER_STYLES)])
            colour = (colours or {}).get(name)
            (line,) = ax.plot(frame["X"], frame["Y"], lw=1.1, ls=style, color=colour,
                              label=labels.get(name, name))  # fmt: skip
            if len(frame):
                ax.plot(frame["X"].iloc[-1], frame["Y"].iloc[-1], "x", color=line.get_color())
        ax.set_title(titles.get(panel, panel))
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=3,
                  frameon=False)  # fmt: skip
    fig.tight_layout()
    return fig


FAILURE_MARKERS = dict(zip(FAILURES, ("o", "s", "X", "D"), strict=True))


def failure_map(
    track: Track,
    path: ClosedPath,
    runs: pd.DataFrame,
    controllers: Mapping[str, str],
    models: Mapping[str, Mapping],
) -> plt.Figure:
    """Where laps are lost: one column per model, the failed runs' last positions on the track
    (colour: controller, marker: failure reason; every η and seed), and below each map the
    failures' lap fraction, stacked by controller. ``path`` is the reference line; ticks along it
    mark every tenth of the lap so that the map and the histogram read together."""
    names = list(dict.fromkeys(runs["model"]))
    _, colours = controller_looks(list(controllers))
    fig, axes = plt.subplots(
        2, max(len(names), 1), figsize=(4.6 * max(len(names), 1), 7.4),
        gridspec_kw={"height_ratios": [3.2, 1.0]}, squeeze=False,
    )  # fmt: skip
    x, y = path.x, path.y
    ticks = [int(np.searchsorted(path.s_points, f / 10 * path.length)) % len(x) for f in range(10)]
    bins = np.linspace(0.0, 1.0, 21)
    for j, model in enumerate(names):
        top, bottom = axes[0, j], axes[1, j]
        mine = runs[runs["model"] == model]
        failed = mine[~mine["success"].astype(bool)]
        draw_track(top, track, centre=False)
        top.plot(closed(x), closed(y), color="0.7", lw=0.7, ls=":")
        for k, i in enumerate(ticks):
            top.annotate(f"{k / 10:.1f}", (x[i], y[i]), fontsize=6, color="0.4",
                         ha="center", va="center")  # fmt: skip
        top.plot(x[0], y[0], marker=">", color="black", ms=7)
        stacks, stack_colours, stack_labels = [], [], []
        for controller, label in controllers.items():
            mine_c = failed[failed["controller"] == controller]
            if mine_c.empty:
                continue
            for reason, marker in FAILURE_MARKERS.items():
                pts = mine_c[mine_c["failure"] == reason]
                if not pts.empty:
                    top.scatter(
                        pts["failure_X"], pts["failure_Y"], s=16, marker=marker,
                        color=colours[controller], alpha=0.7, edgecolors="none",
                    )  # fmt: skip
            stacks.append(mine_c["failure_fraction"].to_numpy(dtype=float))
            stack_colours.append(colours[controller])
            stack_labels.append(label)
        plants = int((failed["failure"] == "plant_diverged").sum())
        title = f"{model_label(models, model)}: {len(failed)} of {len(mine)} runs failed"
        if plants:
            title += f",\n{plants} of them its plant's (plant diverged)"
        top.set_title(title, fontsize=9)
        if stacks:
            bottom.hist(stacks, bins=bins, stacked=True, color=stack_colours, label=stack_labels)
        else:
            bottom.text(0.5, 0.5, "no failures", ha="center", va="center",
                        transform=bottom.transAxes)  # fmt: skip
        bottom.set_xlim(0, 1)
        bottom.set_xlabel("lap fraction at failure")
        bottom.set_ylabel("failed runs")
    handles = [plt.Line2D([], [], color=colours[c], marker="o", ls="", label=label)
               for c, label in controllers.items()]  # fmt: skip
    handles += [plt.Line2D([], [], color="0.3", marker=m, ls="", label=reason.replace("_", " "))
                for reason, m in FAILURE_MARKERS.items()]  # fmt: skip
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), frameon=False,
               fontsize=8, bbox_to_anchor=(0.5, 0.0))  # fmt: skip
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return fig


def controller_looks(controllers: Sequence[str]) -> tuple[dict[str, object], dict[str, str]]:
    """One line style and colour per controller, the same in every panel and figure."""
    styles = {c: CONTROLLER_STYLES[i % len(CONTROLLER_STYLES)] for i, c in enumerate(controllers)}
    return styles, {c: f"C{i % 10}" for i, c in enumerate(controllers)}


def block_diagram(disturbances: DisturbancesSpec) -> plt.Figure:
    """Figure 1: the closed loop of every run (SPEC §5), with where η enters: each disturbance
    source of the config (its class's ``label``) in the box of the loop it acts at."""
    at: dict[str, list[str]] = {stage: [] for stage in STAGES}
    for name, entry in source_entries(disturbances.sources).items():
        cls = source_class(name, entry)
        for stage in cls.stages:
            at[stage].append(cls.label)

    def listed(stage: str, empty: str) -> str:
        return ",\n".join(at[stage]) + " (η > 0)" if at[stage] else empty

    fig, ax = plt.subplots(figsize=(11, 3.4))
    ax.set_xlim(0, 11)
    ax.set_ylim(0, 3.4)
    ax.axis("off")
    w, h, top = 1.55, 0.95, 1.9
    plant = "plant\nlearned · fixed · truth"
    if at["plant"]:
        plant += f"\n({', '.join(at['plant'])} at η > 0)"
    row = [
        ("reference", "reference\n(raceline, §5.2)"),
        ("controller", "controller\nPID · RISE · NMPC\n(internal model, §7)"),
        ("delay", listed("actuation", "actuators")),
        ("plant", plant),
        ("process", listed("after_plant", "(no process\ndisturbance)")),
    ]
    gap = (11 - 0.2 - len(row) * w) / (len(row) - 1)
    boxes = {key: (0.1 + i * (w + gap), top) for i, (key, _) in enumerate(row)}
    boxes["measure"] = (4.4, 0.25)
    texts = dict(row, measure=listed("measurement", "measurement"))
    for key, (x, y) in boxes.items():
        width = 2.2 if key == "measure" else w
        ax.add_patch(plt.Rectangle((x, y), width, h, fc="#eef3fb", ec="black", lw=1))
        ax.text(x + width / 2, y + h / 2, texts[key], ha="center", va="center", fontsize=7.5)

    def arrow(start: tuple[float, float], end: tuple[float, float], label: str = "") -> None:
        ax.annotate("", xy=end, xytext=start, arrowprops={"arrowstyle": "->", "lw": 1})
        if label:
            ax.text((start[0] + end[0]) / 2, (start[1] + end[1]) / 2 + 0.1, label,
                    ha="center", fontsize=7.5)  # fmt: skip

    mid = top + h / 2
    labels = ["p_ref, v_ref", "u = [T, δ]", "", "x"]
    for (a, _), (b, _), label in zip(row, row[1:], labels, strict=False):
        arrow((boxes[a][0] + w, mid), (boxes[b][0], mid), label)
    arrow((boxes["process"][0] + w / 2, top), (boxes["measure"][0] + 2.2, 0.25 + h / 2))
    arrow((boxes["measure"][0], 0.25 + h / 2), (boxes["controller"][0] + w / 2, top),
          "z (measured)")  # fmt: skip
    ax.text(5.5, 3.25, "one lap of ETHZMobil per run: (plant, internal model, controller, η, seed)",
            ha="center", fontsize=9)  # fmt: skip
    return fig
