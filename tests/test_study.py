"""The study's aggregation, tables and scorecard on small hand-made grids of runs."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cape.cli import main
from cape.errors import CapeError
from cape.layout.record import write_run_files, write_timing
from cape.layout.runs import RunId
from cape.specs.run import DisturbancesSpec
from cape.specs.study import StudySpec
from cape.study.aggregate import collect_runs, mean_ci, summarise
from cape.study.claims.scorecard import ClaimSet, Evidence, evaluate_claims
from cape.study.grid import canonical, study_runs
from cape.study.reports.glance import at_a_glance
from cape.study.reports.tables import (
    best_controller,
    controller_parameters,
    success_grid,
    uncertainty_activation,
)

STUDIES = ("truth",)  # the studies whose runs are about their internal model


def _write_run(root: Path, study: str, plant: str, internal: str, controller: str, eta: str,
               seed: int, success: bool, lap: float | None, ey: float,
               replicate: int = 0) -> Path:  # fmt: skip
    """A run's folder as `cape rollout` writes it (cape.layout.record), with these metrics."""
    folder = RunId(study, plant, internal, controller, eta, seed, replicate).folder(root)
    folder.mkdir(parents=True)
    metrics = {
        "study": study, "plant": plant, "internal": internal, "controller": controller, "eta": eta,
        "seed": seed, "replicate": replicate, "success": success,
        "failure": None if success else "off_track",
        "lap_time": lap if success else None, "lap_time_penalised": lap if success else 15.0,
        "mean_abs_ex": ey / 2, "mean_abs_ey": ey, "mean_abs_ex_penalised": ey / 2 if success
        else 0.23, "mean_abs_ey_penalised": ey if success else 0.23, "mean_abs_cte": ey,
        "mean_speed": 1.5, "mean_abs_dT": 0.01, "mean_abs_ddelta": 0.01, "steps": 100,
        "fallbacks": 0, "rescues": 0, "time_limit": 15.0,
    }  # fmt: skip
    digest = write_run_files(folder, metrics, {"t": np.arange(3.0), "X": np.zeros(3)})
    write_timing(folder, {"solve_ms_median": 1.0}, digest)
    return folder / "metrics.json"


def _of_their_folders(paths: list[Path]) -> list[tuple[str | None, Path]]:
    """(study, metrics.json) pairs, each run of the study its metrics.json records."""
    return [(None, p) for p in paths]


def test_mean_ci_is_the_student_t_interval() -> None:
    mean, half, n = mean_ci([1.0, 2.0, 3.0, 4.0])
    # t(0.975, 3) = 3.182446305…, s = 1.290994…, half = t·s/√4
    assert (mean, n) == (2.5, 4)
    assert half == pytest.approx(3.182446305284263 * 1.2909944487358056 / 2, rel=1e-12)
    assert math.isnan(mean_ci([7.0])[1]) and mean_ci([7.0])[0] == 7.0


def test_runs_are_collected_with_their_study_and_model(tmp_path: Path) -> None:
    paths = [
        _write_run(tmp_path, "learned", "epm", "epm", "pid", "0", 0, True, 7.4, 0.02),
        _write_run(tmp_path, "truth", "truth", "epm", "nmpc", "0.5", 1, False, None, 0.1),
    ]
    runs = collect_runs(_of_their_folders(paths), STUDIES)
    assert list(runs["study"]) == ["learned", "truth"]
    assert list(runs["model"]) == ["epm", "epm"]  # the plant, then the internal model
    assert list(runs["eta_label"]) == ["0", "0.5"] and runs["eta"].iloc[1] == 0.5
    assert runs["solve_ms_median"].tolist() == [1.0, 1.0]
    with pytest.raises(CapeError, match="no runs"):
        collect_runs([], STUDIES)


def test_a_runs_study_is_read_from_its_metrics(tmp_path: Path) -> None:
    path = _write_run(tmp_path, "truth", "truth", "epm", "nmpc", "1", 0, True, 7.5, 0.02)
    moved = tmp_path / "elsewhere" / "metrics.json"  # not under a run's folder layout
    shutil.copytree(path.parent, moved.parent)
    assert set(collect_runs([(None, moved)], STUDIES)["study"]) == {"truth"}
    metrics = json.loads(path.read_text())
    del metrics["study"]
    moved.write_text(json.dumps(metrics))
    with pytest.raises(CapeError, match="'study' is a required property"):
        collect_runs([(None, moved)], STUDIES)


def test_a_run_two_studies_ask_for_is_computed_once_and_read_by_both(tmp_path: Path) -> None:
    """The ablation's diagonal (internal = plant) repeats the learned study's runs: the grid
    computes each once, in the first study's folder, and the aggregation reads it for both."""
    config = {"seeds": 1, "studies": {
        "learned": {"plants": ["epm"], "controllers": ["nmpc"]},
        "ablation": {"plants": ["epm"], "internal": ["ddm", "epm"], "controllers": ["nmpc"],
                     "eta": ["1"]},
    }}  # fmt: skip
    spec = StudySpec.from_config(
        {"study": config, "controllers": {}, "disturbances": {"eta": ["0", "1"]}, "training": {}}
    )
    runs = study_runs(spec, lambda controller: controller == "nmpc")
    assert len(runs) == 4  # learned at η 0 and 1, the ablation's two internal models at η 1
    computed = canonical(runs)
    diagonal = RunId("ablation", "epm", "epm", "nmpc", "1", 0)
    assert computed[diagonal] == RunId("learned", "epm", "epm", "nmpc", "1", 0)
    assert len(set(computed.values())) == 3
    assert RunId.parse(diagonal.folder(tmp_path) / "metrics.json") == diagonal
    assert list(tmp_path.glob(RunId.glob())) == []
    with pytest.raises(ValueError, match="not a run folder"):
        RunId.parse(tmp_path / "learned" / "epm" / "seed0")
    path = _write_run(tmp_path, "learned", "epm", "epm", "nmpc", "1", 0, True, 7.1, 0.01)
    table = collect_runs([("learned", path), ("ablation", path)], STUDIES)
    assert sorted(table["study"]) == ["ablation", "learned"]
    assert table["lap_time"].tolist() == [7.1, 7.1]
    assert list(tmp_path.glob(RunId.glob())) == [path.parent]


def test_summary_counts_successes_and_penalises_failures(tmp_path: Path) -> None:
    paths = [
        _write_run(tmp_path, "learned", "epm", "epm", "pid", "1", s, s < 2, 7.0 + s, 0.01 * (s + 1))
        for s in range(4)
    ]
    summary = summarise(collect_runs(_of_their_folders(paths), STUDIES))
    (cell,) = summary.to_dict("records")
    assert (cell["runs"], cell["successes"], cell["success_rate"]) == (4, 2, 0.5)
    assert cell["lap_time_mean"] == pytest.approx(7.5)  # the two laps only
    assert cell["lap_time_penalised_mean"] == pytest.approx((7 + 8 + 15 + 15) / 4)
    assert cell["mean_abs_ey_penalised_mean"] == pytest.approx((0.01 + 0.02 + 0.23 + 0.23) / 4)


def test_the_drawn_interval_stays_where_runs_can_be(tmp_path: Path) -> None:
    # two laps of 7 s and three failures (penalty 15 s, error 0.23 m): the t-interval of the
    # penalised mean reaches above 15 s and the one of the error below 0 m
    paths = [
        _write_run(tmp_path, "learned", "epm", "epm", "pid", "1", s, s < 2, 7.0, 0.01)
        for s in range(5)
    ]
    (cell,) = summarise(collect_runs(_of_their_folders(paths), STUDIES)).to_dict("records")
    lap_mean, lap_half, _ = mean_ci([7.0, 7.0, 15.0, 15.0, 15.0])
    assert cell["lap_time_penalised_ci"] == pytest.approx(lap_half)
    assert lap_mean + lap_half > 15.0
    assert cell["lap_time_penalised_hi"] == 15.0  # the time limit, the most a run can count
    assert cell["lap_time_penalised_lo"] == pytest.approx(lap_mean - lap_half)
    ey_mean, ey_half, _ = mean_ci([0.01, 0.01, 0.23, 0.23, 0.23])
    assert ey_mean - ey_half < 0.0 and cell["mean_abs_ey_penalised_lo"] == 0.0
    assert cell["mean_abs_ey_penalised_hi"] == pytest.approx(ey_mean + ey_half)


def _summary(rows: list[tuple]) -> pd.DataFrame:
    cols = ["model", "controller", "eta", "eta_label", "runs", "successes", "lap_time_mean",
            "lap_time_ci"]  # fmt: skip
    frame = pd.DataFrame(rows, columns=cols)
    frame["success_rate"] = frame["successes"] / frame["runs"]
    return frame


def test_the_best_controller_completes_the_highest_eta_then_laps_fastest() -> None:
    summary = _summary([
        ("dpm-fixed", "pid", 0.0, "0", 2, 2, 7.5, 0.1),
        ("dpm-fixed", "pid", 1.0, "1", 2, 1, 7.9, 0.1),   # half the seeds: completed
        ("dpm-fixed", "nmpc", 0.0, "0", 2, 2, 7.0, 0.1),
        ("dpm-fixed", "nmpc", 1.0, "1", 2, 2, 7.2, 0.1),  # same η, faster
        ("dpm-fixed", "rise", 2.0, "2", 2, 0, np.nan, np.nan),  # never completed
    ])  # fmt: skip
    table = best_controller(summary, {"nmpc": "Nominal NMPC"})
    row = table.iloc[0]
    assert (row["best controller"], row["max η completed"], row["lap time (s)"]) == (
        "Nominal NMPC", 1.0, 7.2,
    )  # fmt: skip


def test_the_success_grid_marks_full_partial_and_no_success() -> None:
    summary = _summary([
        ("epm", "pid", 0.0, "0", 2, 2, 7.25, 0.1),
        ("epm", "pid", 0.5, "0.5", 2, 1, 7.5, np.nan),
        ("epm", "pid", 1.0, "1", 2, 0, np.nan, np.nan),
    ])  # fmt: skip
    grid = success_grid(summary, {"pid": "PID"})
    assert grid.columns.tolist() == ["model", "controller", "η=0", "η=0.5", "η=1"]
    assert grid.iloc[0, 2:].tolist() == ["✓ 7.25", "1/2", "✗"]


def test_config_tables_come_from_the_config(config: dict) -> None:
    table3 = uncertainty_activation(DisturbancesSpec.from_config(config))
    assert table3["η"].tolist() == config["disturbances"]["eta"]
    assert table3.iloc[0, 1:].tolist() == ["–"] * 6  # η = 0: nothing active
    at2 = table3[table3["η"] == "2"].iloc[0]
    assert at2["measurement noise σ (%)"] == "2.0" and at2["process noise σ (%)"] == "4.0"
    table2 = controller_parameters(config["controllers"])
    pid = table2[table2["controller"] == "PID"].set_index("parameter")["value"]
    assert pid["heading.kp"] == 2.2 and pid["lookahead.time"] == 0.05 and pid["lead"] == 0.02
    assert not table2["parameter"].str.startswith("compile").any()


def test_the_scorecard_recomputes_the_claims_per_seed() -> None:
    rows = []
    for seed in range(3):
        for model, lap, ex in (("epm", 6.0, 0.01), ("ddm", 8.0, 0.02), ("dpm", 12.0, 0.04)):
            for controller in ("pid", "anmpc", "nmpc"):
                fail = model == "dpm" and controller == "nmpc"
                rows.append({
                    "study": "learned", "model": model, "controller": controller, "eta": 1.0,
                    "seed": seed, "success": not fail,
                    "lap_time_penalised": lap + seed + (0.1 * seed**2 if model == "epm" else 0),
                    "mean_abs_ex_penalised": ex * (1 + 0.1 * seed), "mean_abs_ey_penalised": ex,
                    "mean_speed": 2.0 if model == "epm" else 1.0,
                })  # fmt: skip
    table, _ = evaluate_claims(Evidence(pd.DataFrame(rows)), ClaimSet(bicycle=None))  # draw 0
    lap = table[table["claim"].str.startswith("adaptive")].set_index("comparison")
    # EPM − DDM is −2, −1.9, −1.6 s over the seeds (EPM 6, 7.1, 8.4 against DDM 8, 9, 10): mean
    # −1.833, sd 0.208, t(0.975, 2 df) = 4.3027, so −1.833 ± 0.517
    half = 4.302653 * np.std([-2.0, -1.9, -1.6], ddof=1) / np.sqrt(3)
    assert lap.loc["EPM − DDM", "ci95_low"] == pytest.approx(-11 / 6 - half)
    assert lap.loc["EPM − DDM", "ci95_high"] == pytest.approx(-11 / 6 + half)
    assert lap.loc["EPM − DDM", "ours"].startswith("-1.83 s (EPM 7.17, DDM 9)")
    assert lap.loc["EPM − DPM", "verdict"] == "holds" == lap.loc["EPM − DDM", "verdict"]
    assert lap.loc["DDM − DPM", "verdict"] == "inconclusive"  # −4 s in every seed: no spread
    # EPM's speed is twice DPM's in every seed: +100 % with no spread, which decides nothing
    speed = table[table["claim"].str.contains("mean_speed") & (table["comparison"] == "EPM vs DPM")]
    assert speed["ci95_low"].iloc[0] == pytest.approx(100.0)
    assert speed["verdict"].iloc[0] == "inconclusive"
    assert speed["why"].iloc[0].startswith("no spread over 3 seeds")
    fails = table[table["claim"].str.startswith("NMPC-family")].set_index("comparison")
    # DPM fails its one NMPC run in every seed, EPM none: −1 each time, a count without spread
    assert fails.loc["EPM − DPM", "ci95_high"] == -1
    assert fails.loc["EPM − DPM", "verdict"] == "inconclusive"
    # EPM and DDM both fail none: a tie, which the interval cannot place on the paper's side
    assert fails.loc["EPM − DDM", "verdict"] == "inconclusive"
    assert "a tie in every draw and seed" in fails.loc["EPM − DDM", "why"]
    # one claim, one label: the grid's 2 NMPCs × 1 η, whichever runs a model has so far
    incomplete = pd.DataFrame(rows).query("not (model == 'ddm' and controller == 'nmpc')")
    labels = evaluate_claims(Evidence(incomplete), ClaimSet(bicycle=None))[0]["claim"]
    assert set(labels[labels.str.startswith("NMPC-family")]) == {
        "NMPC-family failures of 2 runs: EPM fewest"
    }

    page = at_a_glance(table, pd.DataFrame(rows))
    assert page.startswith("# CAPE results at a glance")
    assert "| learned | 27 | 89% |" in page  # 3 of the 27 runs (DPM, nominal NMPC) failed
    holds = int((table["verdict"] == "holds").sum())
    assert f"## Holds for this training draw: {holds} of {len(table)} rows" in page
    undecided = int((table["verdict"] == "inconclusive").sum())
    assert f"## Inconclusive for this training draw: {undecided} of" in page
    assert page.count("\n| adaptive NMPC lap time") == 3  # its three rows in the full table


def test_signal_axes_ignore_the_samples_of_a_diverging_plant() -> None:
    from cape.plots.study import robust_limits

    lap = np.sin(np.linspace(0.0, 20.0, 2000)) * 5.0  # ω within ±5 rad/s
    assert robust_limits(lap) is None  # nothing to hide: Matplotlib's own limits
    diverged = np.concatenate([lap, [-20.0, -60.0, -100.0]])  # the last steps of a failed run
    low, high = robust_limits(diverged)
    assert -7.0 < low < -5.0 and 5.0 < high < 7.0


def test_bars_centre_the_models_a_controller_has_on_its_tick() -> None:
    from cape.plots.study import bars

    rows = [("truth", "pid", 0.0), ("truth", "nmpc", 0.0), ("epm", "nmpc", 0.0)]
    summary = pd.DataFrame(
        [{"model": m, "controller": c, "eta": e, "lap_time_penalised_mean": 10.0,
          "lap_time_penalised_ci": 20.0, "lap_time_penalised_lo": 0.0,
          "lap_time_penalised_hi": 15.0} for m, c, e in rows]
    )  # fmt: skip
    models = {"epm": {"label": "EPM", "color": "#2ca02c"}}
    fig = bars(summary, [("lap_time_penalised", "s")], {"pid": "PID", "nmpc": "NMPC"}, models)
    ax = fig.axes[0]
    centres = sorted(round(p.get_x() + p.get_width() / 2, 6) for p in ax.patches)
    width = ax.patches[0].get_width()
    assert centres == [0.0, round(1 - width / 2, 6), round(1 + width / 2, 6)]
    # the error bar of a 20 s half-width stays within 0–15 s
    tops = [seg[:, 1].max() for line in ax.collections for seg in line.get_segments()]
    assert max(tops) == pytest.approx(15.0)
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["EPM", "true model"]


def test_the_aggregation_reads_a_shared_run_where_the_workflow_computed_it(tmp_path: Path) -> None:
    """A run two studies share is computed in the folder of the config's first study that has
    it: `cape aggregate` builds the grid with the rules' function (cape.study.grid.study_grid)
    from the sections the rule passes, in the config's order (learned before ablation)."""
    studies = {"learned": {"plants": ["epm"], "controllers": ["nmpc"]},
               "ablation": {"plants": ["epm"], "internal": ["epm", "truth"],
                            "controllers": ["nmpc"]}}  # fmt: skip
    config = {"study": {"seeds": 1, "studies": studies}, "disturbances": {"eta": ["0"]},
              "controllers": {"nmpc": {}}, "training": {"replicates": 1}}  # fmt: skip
    _write_run(tmp_path, "learned", "epm", "epm", "nmpc", "0", 0, True, 7.4, 0.02)
    _write_run(tmp_path, "ablation", "epm", "truth", "nmpc", "0", 0, True, 7.5, 0.03)
    out = tmp_path / "runs.parquet"
    as_the_rule_passes_it = json.dumps(config)  # cape.workflow.job_files.JobFiles.write_grid
    main(["aggregate", "--root", str(tmp_path), "--out", str(out), "--summary",
          str(tmp_path / "summary.parquet"), "--config-json", as_the_rule_passes_it])  # fmt: skip
    runs = pd.read_parquet(out)
    cells = set(zip(runs["study"], runs["internal"], runs["lap_time"], strict=True))
    assert cells == {("learned", "epm", 7.4), ("ablation", "epm", 7.4), ("ablation", "truth", 7.5)}


@pytest.mark.parametrize(
    ("sections", "message"),
    [
        ({}, "lacks the `controllers` section"),
        ({"controllers": {"pid": {}}, "training": {"replicates": 1},
          "study": {"seeds": 1, "studies": {"t": {"plants": ["truth"], "controllers": ["pidd"]}}}},
         "names controller 'pidd'"),
    ],
)  # fmt: skip
def test_aggregate_names_what_its_grid_lacks(tmp_path: Path, capsys, sections, message) -> None:
    """The grid `cape aggregate` builds from --config-json: a missing section or an unknown
    controller is one line and exit 2, never a traceback."""
    config = {"study": {"seeds": 1, "studies": {}}, "disturbances": {"eta": ["0"]}, **sections}
    out, summary = str(tmp_path / "r.parquet"), str(tmp_path / "s.parquet")
    code = main(["aggregate", "--root", str(tmp_path), "--out", out, "--summary", summary,
                 "--config-json", json.dumps(config)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing written
