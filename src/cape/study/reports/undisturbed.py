"""The runs without disturbances (η = 0): who laps which plant, and what the car did first
where it did not.

At η = 0 every disturbance source is off (SPEC §6), so a failure there is the controller's or
the plant's alone. Each failed cell is given its measured cause: a failed training (SPEC §4,
``cape.training.health``), or how far the car slid before it left the track, beside the
ground-truth car under the same controller (the project's control experiment). A learned plant
that lets the car slide far past anything the true car does is a learned model outside its
data, not a controller's fault (docs/closed-loop.md, "the feedback laws at η = 0").
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from cape.layout.names import TRUTH
from cape.layout.record import read_series
from cape.vehicle.dynamics import slip_angles
from cape.vehicle.params import GROUND_TRUTH

#: Samples slower than this (m/s) are left out of a run's slip extent: at a standstill the slip
#: angle's atan2 is ill-conditioned and says nothing about the tyres.
MIN_SPEED = 0.5


def slip_extent(series: pd.DataFrame) -> tuple[float, float]:
    """The largest |front| and |rear| slip angle (rad) of one run's time series, over the
    samples faster than ``MIN_SPEED`` (the geometry is the car's, SPEC §1)."""
    moving = series[series["vx"] >= MIN_SPEED]
    if moving.empty:
        return float("nan"), float("nan")
    front, rear = slip_angles(
        moving["vx"].to_numpy(),
        moving["vy"].to_numpy(),
        moving["omega"].to_numpy(),
        moving["delta_applied"].to_numpy(),
        {"lf": GROUND_TRUTH.lf, "lr": GROUND_TRUTH.lr},
    )
    return float(np.max(np.abs(front))), float(np.max(np.abs(rear)))


def _extent(
    rows: pd.DataFrame, root: Path, seen: dict[Path, tuple[float, float]]
) -> tuple[float, float]:
    """The largest slip angles over several runs (their folders are relative to ``root``);
    ``seen`` keeps each run's, since the same ground-truth laps serve several cells."""
    for folder in (root / f for f in rows["folder"] if root / f not in seen):
        seen[folder] = slip_extent(read_series(folder))
    extents = [seen[root / f] for f in rows["folder"]]
    if not extents:
        return float("nan"), float("nan")
    front, rear = zip(*extents, strict=True)
    return float(np.nanmax(front)), float(np.nanmax(rear))


def _reference(
    runs: pd.DataFrame, truth_plant: str, controller: str, internal: str
) -> pd.DataFrame:
    """The ground-truth plant's laps at η = 0 under the same controller, with the same internal
    model where the controller has one, else the true one."""
    base = runs[
        runs["plant"].eq(truth_plant)
        & runs["controller"].eq(controller)
        & runs["eta"].astype(float).eq(0.0)
        & runs["success"].astype(bool)
    ]
    same = base[base["internal"].eq(internal)]
    return same if len(same) else base[base["internal"].eq(truth_plant)]


def undisturbed(
    runs: pd.DataFrame,
    study: str,
    failed: Mapping[int, Mapping[str, str]],
    truth_plant: str = TRUTH,
    root: str | Path = ".",
) -> tuple[pd.DataFrame, list[str]]:
    """Laps at η = 0 per replicate and plant of ``study`` (columns: controllers, cells
    ``laps/runs``), and one line per cell with a failure naming its measured cause.
    ``failed`` is ``failed_draws``' replicate → model → reason; ``root`` is the folder the
    runs' ``folder`` column is relative to (the repository)."""
    root, seen = Path(root), {}
    at_rest = runs[runs["study"].eq(study) & runs["eta"].astype(float).eq(0.0)]
    controllers = list(dict.fromkeys(at_rest["controller"]))
    table, causes = [], []
    for (replicate, plant), group in at_rest.groupby(["replicate", "plant"], sort=True):
        row: dict[str, object] = {"replicate": int(replicate), "plant": plant}
        for controller in controllers:
            cell = group[group["controller"].eq(controller)]
            laps = int(cell["success"].astype(bool).sum())
            row[controller] = f"{laps}/{len(cell)}" if len(cell) else "–"
            if len(cell) and laps < len(cell):
                internal = str(cell["internal"].iloc[0])
                cause = _cause(
                    cell, runs, failed.get(int(replicate), {}), truth_plant, internal, root, seen
                )
                causes.append(
                    f"replicate {replicate}, {plant.upper()} plant, {controller}: "
                    f"{len(cell) - laps} of {len(cell)} did not lap; {cause}"
                )
        table.append(row)
    return pd.DataFrame(table), causes


def _cause(
    cell: pd.DataFrame,
    runs: pd.DataFrame,
    failed: Mapping[str, str],
    truth_plant: str,
    internal: str,
    root: Path,
    seen: dict[Path, tuple[float, float]],
) -> str:
    """The measured cause of one cell's failures (see the module's docstring)."""
    lost = cell[~cell["success"].astype(bool)]
    reasons = ", ".join(f"{r} {n}×" for r, n in lost["failure"].value_counts().items())
    plant = str(cell["plant"].iloc[0])
    trainings = [
        f"this replicate's {m.upper()} training failed (the trainings' table gives why)"
        for m in failed
        if m in (plant, internal)
    ]
    front, rear = _extent(lost, root, seen)
    reference = _reference(runs, truth_plant, str(cell["controller"].iloc[0]), internal)
    ref_front, ref_rear = _extent(reference, root, seen)
    laps = f"{len(reference)} lap{'s' if len(reference) != 1 else ''}"
    slid = f"before it the slip angles reached {front:.2f} rad front, {rear:.2f} rad rear" + (
        f"; the ground-truth car under the same controller stays within {ref_front:.2f} and "
        f"{ref_rear:.2f} rad ({laps})"
        if len(reference)
        else "; the truth study has no lap of this controller at η = 0 to compare with"
    )
    diverged = int(lost["failure"].eq("plant_diverged").sum())
    if diverged:
        trainings.insert(
            0,
            f"{diverged} of them the plant's, not the controller's: the learned plant left "
            "its training data's envelope (plant_diverged, SPEC §5.3)",
        )
    if trainings:
        return f"{reasons}; " + "; ".join(trainings) + f"; {slid}"
    if len(reference) and (front > 2 * ref_front or rear > 2 * ref_rear):
        return (
            f"{reasons}; the plant's training passed its checks, but {slid}: the learned plant "
            "let the car slide more than twice as far as the true car (a learned model beyond "
            "its data; docs/closed-loop.md)"
        )
    return f"{reasons}; {slid}; not explained"
