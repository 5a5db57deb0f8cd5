"""Table 9, the leaderboard (cape.study.claims.leaderboard): hand-made runs, hand-computed
values."""

from __future__ import annotations

import pandas as pd
import pytest
from scipy import stats

from cape.study.claims.leaderboard import HIGHER, leaderboard, metric_of
from cape.study.stats.verdicts import INCONCLUSIVE

NOISE = [0.2, -0.2, 0.1, -0.1, 0.0]  # each draw's seeds around its lap time (mean 0)
LAPS = {  # the adaptive NMPC's lap time per draw
    "epm": [7.0, 7.2, 6.9],
    "ddm": [8.0, 8.3, 8.1],  # 1.0, 1.1, 1.2 s slower than EPM in each draw
    "dpm": [6.5, 8.7, 7.7],  # −0.5, +1.5, +0.8: the draws disagree
    "newcomer": [7.1, 7.3, 7.0],  # a model added by its config entry alone
}


def _runs() -> pd.DataFrame:
    rows = [
        {"model": model, "controller": "anmpc", "eta": 0.0, "seed": seed, "replicate": r,
         "success": True, "lap_time_penalised": lap + noise}
        for model, laps in LAPS.items()
        for r, lap in enumerate(laps)
        for seed, noise in enumerate(NOISE)
    ]  # fmt: skip
    return pd.DataFrame(rows)


def test_every_model_is_ranked_with_its_interval_and_its_effect_against_the_reference() -> None:
    models = ["dpm", "ddm", "epm", "newcomer", "untrained"]  # the last has no runs: no row
    openloop = {r: pd.DataFrame({"model": models[:4], "test_rmse_omega": [4, 3, 2, r + 1.0]})
                for r in range(3)}  # fmt: skip
    table = leaderboard(_runs(), models, "epm", "anmpc_lap_time", openloop=openloop)
    assert list(table["model"]) == ["epm", "newcomer", "dpm", "ddm"]  # by mean lap time
    assert list(table["rank"]) == [1, 2, 3, 4]
    rows = table.set_index("model")
    label = metric_of("anmpc_lap_time").label
    half = stats.t.ppf(0.975, 2) * 0.1 / 3**0.5  # DDM − EPM: effects 1.0, 1.1, 1.2 (sd 0.1)
    ddm = rows.loc["ddm"]
    assert ddm["effect vs reference"] == pytest.approx(1.1)
    assert (ddm["ci95_low"], ddm["ci95_high"]) == (pytest.approx(1.1 - half),
                                                   pytest.approx(1.1 + half))  # fmt: skip
    assert ddm["verdict vs reference"] == HIGHER and ddm["draws needed"] == ""
    epm_sd = pd.Series(LAPS["epm"]).std()
    low = 7.0333333 - stats.t.ppf(0.975, 2) * epm_sd / 3**0.5
    assert rows.loc["epm", label].startswith("7.03 [") and f"{low:.3g}" in rows.loc["epm", label]
    assert rows.loc["epm", "verdict vs reference"] == "the reference"
    dpm = rows.loc["dpm"]
    assert dpm["verdict vs reference"] == INCONCLUSIVE and dpm["draws needed"] != ""
    assert rows.loc["newcomer", "test_rmse_omega"] == pytest.approx(2.0)  # mean of 1, 2, 3
    assert rows.loc["newcomer", "NMPC-family failures per seed"] == "0 (no spread over 3 draws)"


def test_a_model_without_the_primary_metric_is_not_evaluated_and_unranked() -> None:
    """A model whose runs hold no adaptive NMPC lap (its controller absent) has no place in the
    ranking: `not evaluated`, no rank, and why; the others are ranked as before."""
    runs = _runs()
    runs.loc[runs["model"] == "newcomer", "controller"] = "pid"
    table = leaderboard(runs, list(LAPS), "epm", "anmpc_lap_time")
    rows = table.set_index("model")
    assert list(table["model"][:3]) == ["epm", "dpm", "ddm"]
    assert list(table["rank"][:3]) == [1, 2, 3] and pd.isna(rows.loc["newcomer", "rank"])
    assert rows.loc["newcomer", "verdict vs reference"] == "not evaluated"
    assert "no value of the primary metric" in rows.loc["newcomer", "why"]


def test_a_board_without_the_reference_model_says_so_on_every_row() -> None:
    runs = _runs()
    table = leaderboard(runs[runs["model"] != "epm"], list(LAPS), "epm", "anmpc_lap_time")
    assert set(table["verdict vs reference"]) == {"no reference runs"}
    assert table["why"].str.contains("EPM \\(study.reference_model\\) has no run").all()


def test_a_draw_whose_training_failed_is_left_out_and_a_point_decides_nothing() -> None:
    """DDM's draw 1 failed (it stood in at the cap): its runs leave the board, DDM − EPM rests
    on draws 0 and 2 and says so; with one draw left the effect is a point, undecided."""
    runs = _runs()
    openloop = {r: pd.DataFrame({"model": ["epm", "ddm"], "test_rmse_omega": [2.0, 10.0 ** r]})
                for r in range(3)}  # fmt: skip
    table = leaderboard(runs, ["epm", "ddm"], "epm", "anmpc_lap_time", openloop=openloop,
                        failed={1: {"ddm": "stalled"}})  # fmt: skip
    ddm = table.set_index("model").loc["ddm"]
    assert ddm["effect vs reference"] == pytest.approx(1.1)  # (1.0 + 1.2) / 2
    assert ddm["test_rmse_omega"] == pytest.approx(50.5)  # draws 0 and 2: (1 + 100) / 2
    assert "rests on 2 of the study's 3 draws" in ddm["why"]
    table = leaderboard(runs, ["epm", "ddm"], "epm", "anmpc_lap_time",
                        failed={1: {"ddm": "stalled"}, 2: {"ddm": "bar"}})  # fmt: skip
    ddm = table.set_index("model").loc["ddm"]
    assert ddm["verdict vs reference"] == INCONCLUSIVE
    assert ddm["why"].startswith("one draw of 3 has a value")


def test_a_model_whose_every_draw_failed_stays_on_the_board_unranked() -> None:
    """Every DDM draw stood in for a failed training: DDM keeps its row, `not evaluated` and
    unranked, saying its draws did not train; with EPM's draws failed instead, the board says
    on every row that the reference has no run whose training worked."""
    runs = _runs()
    every = {r: {"ddm": "bar"} for r in range(3)}
    table = leaderboard(runs, ["epm", "ddm", "dpm"], "epm", "anmpc_lap_time", failed=every)
    rows = table.set_index("model")
    assert list(table["model"]) == ["epm", "dpm", "ddm"] and pd.isna(rows.loc["ddm", "rank"])
    assert rows.loc["ddm", "verdict vs reference"] == "not evaluated"
    assert "none of its draws in this study trained" in rows.loc["ddm", "why"]
    gone = {r: {"epm": "bar"} for r in range(3)}
    table = leaderboard(runs, ["epm", "ddm", "dpm"], "epm", "anmpc_lap_time", failed=gone)
    others = table[table["model"] != "epm"]
    assert set(others["verdict vs reference"]) == {"no reference runs"}
    assert others["why"].str.endswith("whose training worked").all()
