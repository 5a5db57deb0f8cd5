"""The η = 0 section of RESULTS.md: laps per replicate and plant, and the measured cause of
every cell that did not lap, on hand-made runs."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cape.layout.record import write_run_files, write_timing
from cape.layout.runs import RunId
from cape.study.aggregate import collect_runs
from cape.study.reports.undisturbed import slip_extent, undisturbed

STUDIES = ()  # no study here is about its internal model


def _run(root: Path, study: str, plant: str, controller: str, seed: int, success: bool,
         omega: float, replicate: int = 0) -> Path:  # fmt: skip
    """A run at η = 0 whose car drives at 1 m/s with a constant yaw rate ``omega``, steering
    0.1 rad (so its slip angles are known by hand)."""
    internal = "truth" if plant == "truth" else plant
    folder = RunId(study, plant, internal, controller, "0", seed, replicate).folder(root)
    folder.mkdir(parents=True)
    metrics = {
        "study": study, "plant": plant, "internal": internal, "controller": controller,
        "eta": "0", "seed": seed, "replicate": replicate, "success": success,
        "failure": None if success else "off_track", "lap_time": 7.0 if success else None,
        "lap_time_penalised": 7.0 if success else 15.0, "mean_abs_ex": 0.01,
        "mean_abs_ey": 0.01, "mean_abs_ex_penalised": 0.01, "mean_abs_ey_penalised": 0.01,
        "mean_abs_cte": 0.01, "mean_speed": 1.0, "mean_abs_dT": 0.01, "mean_abs_ddelta": 0.01,
        "steps": 4, "fallbacks": 0, "rescues": 0, "time_limit": 15.0,
    }  # fmt: skip
    n = 4
    series = {
        "t": np.arange(n) * 0.02,
        "vx": np.array([0.1, 1.0, 1.0, 1.0]),  # the first sample is too slow to count
        "vy": np.zeros(n),
        "omega": np.array([50.0, omega, omega, omega]),
        "delta_applied": np.full(n, 0.1),
    }
    digest = write_run_files(folder, metrics, series)
    write_timing(folder, {"solve_ms_median": 1.0}, digest)
    return folder / "metrics.json"


def test_slip_extent_by_hand() -> None:
    series = pd.DataFrame(
        {"vx": [0.2, 1.0, 2.0], "vy": [0.0, 0.0, 0.1], "omega": [9.0, 1.0, 0.0],
         "delta_applied": [0.3, 0.1, -0.05]}
    )  # fmt: skip
    front, rear = slip_extent(series)
    # αf = δ − atan2(lf·ω + vy, vx), αr = atan2(lr·ω − vy, vx), lf 0.029, lr 0.033 (SPEC §1);
    # the 0.2 m/s sample is left out: 1 m/s: αf 0.1 − atan(0.029) = 0.0710, αr atan(0.033)
    # = 0.0330; 2 m/s: αf −0.05 − atan(0.05) = −0.0999, αr atan(−0.05) = −0.0500
    assert front == pytest.approx(0.05 + math.atan(0.05), abs=1e-12)
    assert rear == pytest.approx(math.atan(0.05), abs=1e-12)
    assert all(math.isnan(v) for v in slip_extent(series.iloc[:1]))


def test_each_failed_cell_names_its_cause(tmp_path: Path) -> None:
    paths = [
        *(_run(tmp_path, "truth", "truth", "pid", s, True, omega=1.0) for s in range(2)),
        *(_run(tmp_path, "learned", "dpm", "pid", s, True, omega=1.0) for s in range(2)),
        # replicate 1: DPM slides far past the true car; DDM's training failed
        *(_run(tmp_path, "learned", "dpm", "pid", s, False, 30.0, 1) for s in range(2)),
        _run(tmp_path, "learned", "ddm", "pid", 0, False, omega=1.0, replicate=1),
        _run(tmp_path, "learned", "ddm", "pid", 1, True, omega=1.0, replicate=1),
        # replicate 2: DDM fails without sliding: nothing measured explains it
        _run(tmp_path, "learned", "ddm", "pid", 0, False, omega=1.2, replicate=2),
    ]
    runs = collect_runs([(None, p) for p in paths], STUDIES)
    failed = {1: {"ddm": "training loss stalled"}}
    table, causes = undisturbed(runs, "learned", failed)

    cells = {(r.replicate, r.plant): r.pid for r in table.itertuples()}
    assert cells == {(0, "dpm"): "2/2", (1, "ddm"): "1/2", (1, "dpm"): "0/2", (2, "ddm"): "0/1"}
    assert len(causes) == 3  # every cell short of its runs, and no other
    by_cell = {c.split(":")[0]: c for c in causes}
    slid = by_cell["replicate 1, DPM plant, pid"]
    assert "2 of 2 did not lap" in slid and "off_track 2×" in slid
    assert "more than twice as far as the true car" in slid
    rear_slid, rear_true = math.atan(0.033 * 30.0), math.atan(0.033)
    assert f"{rear_slid:.2f} rad rear" in slid and f"and {rear_true:.2f} rad (2 laps)" in slid
    assert "this replicate's DDM training failed" in by_cell["replicate 1, DDM plant, pid"]
    assert by_cell["replicate 2, DDM plant, pid"].endswith("not explained")


def test_each_plants_failures_are_counted_apart_from_its_controllers() -> None:
    """RESULTS.md's count: per study and plant, the failed runs and how many of them were the
    plant's own (plant_diverged), beside the controllers' (off track, timeout)."""
    from cape.study.reports.tables import plant_failures

    runs = pd.DataFrame(
        {
            "study": ["learned"] * 5 + ["truth"] * 2,
            "plant": ["dpm", "dpm", "dpm", "epm", "epm", "truth", "truth"],
            "success": [False, False, True, True, False, True, False],
            "failure": ["plant_diverged", "plant_diverged", None, None, "off_track", None,
                        "timeout"],
        }
    )  # fmt: skip
    table = plant_failures(runs).set_index(["study", "plant"])
    assert table.loc[("learned", "dpm")].tolist() == [3, 2, 2]
    assert table.loc[("learned", "epm")].tolist() == [2, 1, 0]
    assert table.loc[("truth", "truth")].tolist() == [2, 1, 0]
