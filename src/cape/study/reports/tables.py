"""The study's tables (SPEC §9, tables 2, 3, 5, 6, 7) as data frames, from the config and the
aggregated runs. The notebooks only call these and write the results."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import pandas as pd

from cape.closedloop.disturbances import is_active, source_class, source_entries
from cape.closedloop.rollout import FAILURES as FAILURE_REASONS
from cape.specs.run import DisturbancesSpec

PRESENTATION = ("module", "type", "label", "color")


def _flatten(entry: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    rows: list[tuple[str, Any]] = []
    for key, value in entry.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            rows += _flatten(value, f"{name}.")
        else:
            rows.append((name, value))
    return rows


def controller_parameters(controllers: Mapping[str, Any]) -> pd.DataFrame:
    """Table 2: every controller's settings from the config (one row per parameter)."""
    rows = []
    for name, entry in controllers.items():
        settings = {k: v for k, v in entry.items() if k not in PRESENTATION}
        for key, value in _flatten(settings):
            if key.startswith("compile"):
                continue  # how the solver is built, not a parameter of the law
            shown = ", ".join(map(str, value)) if isinstance(value, list) else value
            rows.append({"controller": entry.get("label", name), "parameter": key, "value": shown})
    return pd.DataFrame(rows)


def uncertainty_activation(disturbances: DisturbancesSpec) -> pd.DataFrame:
    """Table 3: which source is active at each η of the grid, with its size there: a column
    per source of the config (its class's ``column``, its ``cell``), in the config's order."""
    entries = source_entries(disturbances.sources)
    classes = {name: source_class(name, entry) for name, entry in entries.items()}
    rows = []
    for label in disturbances.eta:
        eta = float(label)
        row: dict[str, Any] = {"η": label}
        for name, entry in entries.items():
            cls = classes[name]
            row[cls.column] = cls.cell(entry, eta) if is_active(entry, eta) else "–"
        rows.append(row)
    return pd.DataFrame(rows)


def completed(summary: pd.DataFrame) -> pd.Series:
    """A cell counts as completed when at least half of its seeds lap."""
    return summary["success_rate"] >= 0.5


def best_controller(summary: pd.DataFrame, labels: Mapping[str, str]) -> pd.DataFrame:
    """Table 5: per model, the controller that completes the highest η (ties: faster lap), with
    that η and its mean lap time."""
    rows = []
    done = summary[completed(summary)]
    for model, group in done.groupby("model", sort=True):
        best = None
        for controller, cells in group.groupby("controller"):
            top = cells.loc[cells["eta"].idxmax()]
            key = (float(top["eta"]), -float(top["lap_time_mean"]))
            if best is None or key > best[0]:
                best = (key, controller, top)
        assert best is not None
        _, controller, top = best
        rows.append(
            {
                "model": model,
                "best controller": labels.get(controller, controller),
                "max η completed": float(top["eta"]),
                "lap time (s)": float(top["lap_time_mean"]),
                "± 95 % CI": float(top["lap_time_ci"]),
            }
        )
    return pd.DataFrame(rows)


def metrics_at(summary: pd.DataFrame, eta: float, labels: Mapping[str, str]) -> pd.DataFrame:
    """Table 6: failure-penalised e_x, e_y, mean speed and lap time per model × controller at
    one η, with CIs and the success rate."""
    cells = summary[summary["eta"] == eta]
    rows = []
    for _, c in cells.sort_values(["model", "controller"]).iterrows():
        rows.append(
            {
                "model": c["model"],
                "controller": labels.get(c["controller"], c["controller"]),
                "mean |e_x| (m)": c["mean_abs_ex_penalised_mean"],
                "± CI e_x": c["mean_abs_ex_penalised_ci"],
                "mean |e_y| (m)": c["mean_abs_ey_penalised_mean"],
                "± CI e_y": c["mean_abs_ey_penalised_ci"],
                "mean speed (m/s)": c["mean_speed_mean"],
                "lap time (s)": c["lap_time_penalised_mean"],
                "± CI lap": c["lap_time_penalised_ci"],
                "success": f"{int(c['successes'])}/{int(c['runs'])}",
            }
        )
    return pd.DataFrame(rows)


def success_grid(summary: pd.DataFrame, labels: Mapping[str, str]) -> pd.DataFrame:
    """Table 7: ✓ and the mean lap time where every seed laps, ✗ where none does, k/n between."""

    def mark(c: pd.Series) -> str:
        if c["successes"] == c["runs"]:
            return f"✓ {c['lap_time_mean']:.2f}"
        if c["successes"] == 0:
            return "✗"
        return f"{int(c['successes'])}/{int(c['runs'])}"

    frame = summary.assign(mark=summary.apply(mark, axis=1))
    frame["controller"] = frame["controller"].map(lambda c: labels.get(c, c))
    grid = frame.pivot_table(
        index=["model", "controller"], columns="eta_label", values="mark", aggfunc="first"
    )
    order = sorted(grid.columns, key=float)
    grid = grid[order]
    grid.columns = [f"η={c}" for c in order]
    return grid.reset_index()


def failure_summary(runs: pd.DataFrame, labels: Mapping[str, str]) -> pd.DataFrame:
    """Per model and controller: runs, failures by reason, the median lap fraction where runs
    failed, and the failures preceded by solver fallbacks (``fallbacks_before_failure`` > 0)."""
    rows = []
    for (model, controller), group in runs.groupby(["model", "controller"], sort=True):
        failed = group[~group["success"].astype(bool)]
        reasons = failed["failure"].value_counts()
        fraction = failed["failure_fraction"].astype(float) if len(failed) else None
        before = failed.get("fallbacks_before_failure")
        rows.append(
            {
                "model": model,
                "controller": labels.get(controller, controller),
                "runs": len(group),
                "failures": len(failed),
                **{reason: int(reasons.get(reason, 0)) for reason in FAILURE_REASONS},
                "median lap fraction": float(fraction.median()) if fraction is not None else None,
                "after fallbacks": int((before.fillna(0) > 0).sum()) if before is not None else 0,
            }
        )
    return pd.DataFrame(rows)


def plant_failures(runs: pd.DataFrame) -> pd.DataFrame:
    """Per study and plant: runs, failed runs, and how many of those its plant's
    (``plant_diverged``: a learned plant that left its training data's envelope, SPEC §5.3)
    rather than the controllers'."""
    failed = ~runs["success"].astype(bool)
    reasons = runs["failure"] if "failure" in runs else pd.Series(None, index=runs.index)
    plants = reasons.eq("plant_diverged")
    frame = runs.assign(_failed=failed, _plant=plants)
    table = frame.groupby(["study", "plant"], sort=False).agg(
        runs=("_failed", "size"), failures=("_failed", "sum"), plant_diverged=("_plant", "sum")
    )
    table = table.reset_index().astype({"failures": int, "plant_diverged": int})
    return table.rename(columns={"plant_diverged": "the plant's (plant diverged)"})
