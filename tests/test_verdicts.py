"""Three-valued verdicts (SPEC §10) from the two-level interval, on cases worked by hand and on
hand-made runs; training health (SPEC §4); the grid's replicates (SPEC §8)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from cape.models.health import outliers, training_checks, training_health
from cape.study.grid import RunId, canonical, study_runs
from cape.study.scorecard import Context, learned_claims
from cape.study.verdicts import (
    CONTRADICTED,
    HOLDS,
    INCONCLUSIVE,
    Interval,
    combine,
    exact_verdict,
    interval,
    two_level_distribution,
    verdict,
)


def test_the_two_level_distribution_matches_a_case_worked_by_hand() -> None:
    """Replicates A = {0, 1} and B = {3, 3}. The outer draw picks (A, A) with probability 1/4,
    (A, B) 1/2, (B, B) 1/4; A's inner mean is 0, 0.5, 1 with 1/4, 1/2, 1/4. So the statistic is
    0 with probability 1/4 · 1/16 = 1/64, 0.25 with 4/64, 3 with 1/4, and its mean is the mean of
    the replicates' means, 1.75. The 2.5 % quantile falls in the atom at 0.25 (cumulative
    1/64 … 5/64) and the 97.5 % one in the atom at 3 (3/4 … 1): the interval is [0.25, 3]."""
    effects = {0: [0.0, 1.0], 1: [3.0, 3.0]}
    dist = two_level_distribution(effects, resamples=200_000, seed=1)
    n = dist.size

    def close(p: float, value: float) -> None:
        observed = np.mean(np.isclose(dist, value))
        assert abs(observed - p) < 4 * np.sqrt(p * (1 - p) / n), (value, observed, p)

    close(1 / 64, 0.0)
    close(4 / 64, 0.25)
    close(1 / 4, 3.0)
    close(1 / 2 * 1 / 4, 1.5)  # (A, B) with A's inner mean 0
    assert dist.mean() == pytest.approx(1.75, abs=0.01)
    span = interval(effects, resamples=200_000, seed=1)
    assert span.estimate == 1.75
    assert (span.low, span.high) == (pytest.approx(0.25), pytest.approx(3.0))
    assert (span.replicates, span.values) == (2, 4)


def test_one_replicate_is_the_ordinary_bootstrap_over_seeds() -> None:
    """With one replicate the two-level draw is scipy's percentile bootstrap of the mean."""
    x = np.array([0.3, -0.1, 0.8, 0.2, 0.5, 0.05, 0.6])
    ours = interval({0: list(x)}, resamples=100_000, seed=3)
    theirs = stats.bootstrap(
        (x,), np.mean, n_resamples=100_000, method="percentile", random_state=4
    ).confidence_interval
    assert ours.low == pytest.approx(theirs.low, abs=0.01)
    assert ours.high == pytest.approx(theirs.high, abs=0.01)
    assert ours.estimate == pytest.approx(x.mean())


def test_a_replicate_weighs_the_same_whatever_its_seeds() -> None:
    span = interval({0: [1.0] * 9, 1: [3.0]})
    assert span.estimate == 2.0  # the mean of the replicates' means, not of the 10 values


def test_the_verdict_compares_the_interval_with_zero_on_the_papers_side() -> None:
    below, across, above = (
        Interval(-2, -3, -1, 1, 5),
        Interval(0.1, -1, 2, 1, 5),
        Interval(2, 1, 3, 1, 5),
    )
    assert verdict(below, -1) == HOLDS and verdict(above, -1) == CONTRADICTED
    assert verdict(above, +1) == HOLDS and verdict(below, +1) == CONTRADICTED
    assert verdict(across, -1) == INCONCLUSIVE == verdict(across, +1)
    assert verdict(interval({}), -1) == INCONCLUSIVE  # no values
    assert exact_verdict(-0.5, -1) == HOLDS and exact_verdict(0.0, -1) == CONTRADICTED
    assert combine([HOLDS, HOLDS]) == HOLDS
    assert combine([HOLDS, INCONCLUSIVE]) == INCONCLUSIVE
    assert combine([INCONCLUSIVE, CONTRADICTED, HOLDS]) == CONTRADICTED


def _runs(laps: dict[str, list[list[float]]]) -> pd.DataFrame:
    """Hand-made learned-study runs: model → replicate → the ANMPC's lap per seed (η 0 only)."""
    rows = []
    for model, replicates in laps.items():
        for replicate, seeds in enumerate(replicates):
            for seed, lap in enumerate(seeds):
                rows.append({"study": "learned", "model": model, "plant": model,
                             "internal": model, "controller": "anmpc", "eta": 0.0, "seed": seed,
                             "replicate": replicate, "success": True,
                             "lap_time_penalised": lap})  # fmt: skip
    return pd.DataFrame(rows)


def test_hand_made_runs_give_one_case_of_each_verdict() -> None:
    """EPM laps 1 s faster than DDM in every seed of both replicates (holds); DPM is 1 s faster
    than DDM (the paper says slower: contradicted); EPM against DPM is a tie within the seeds'
    spread (inconclusive). Replicate 1 of DPM failed to train: the `trained` pool drops it."""
    noise = [0.2, -0.2, 0.1, -0.1, 0.0]
    ddm = [[8.0 + n for n in noise], [8.1 + n for n in noise]]
    epm = [[7.0 + n for n in noise], [7.1 + n for n in noise]]
    dpm = [[7.0 - n for n in noise], [7.1 - n for n in noise]]
    context = Context(failed={1: {"dpm": "stalled"}})
    rows = {
        r["comparison"]: r
        for r in learned_claims(_runs({"epm": epm, "ddm": ddm, "dpm": dpm}), context)
        if r["claim"].startswith("adaptive NMPC lap time")
    }
    assert rows["EPM − DDM"]["verdict"] == HOLDS
    assert rows["EPM − DDM"]["verdict rep0"] == HOLDS == rows["EPM − DDM"]["verdict rep1"]
    assert rows["DDM − DPM"]["verdict"] == CONTRADICTED
    assert rows["EPM − DPM"]["verdict"] == INCONCLUSIVE
    assert rows["EPM − DDM"]["why"] == ""
    assert rows["DDM − DPM"]["why"] == "not explained; training failed: DPM replicate 1"
    assert rows["EPM − DPM"]["why"].startswith("within the spread of the seeds in every replicate")
    assert rows["EPM − DDM"]["ci95_high"] < 0 < rows["DDM − DPM"]["ci95_low"]
    assert rows["EPM − DDM"]["replicates"] == 2


def test_a_failed_training_is_flagged_by_each_check() -> None:
    settings = {"models": ["ddm", "epm"], "val_rmse_max": {"vx": 1e-3, "vy": 1e-3, "omega": 2e-3},
                "stall": {"after": 5, "min_drop": 0.01}, "outlier_factor": 10}  # fmt: skip
    good = {"vx": 3e-5, "vy": 1e-4, "omega": 8e-4}
    falling = list(np.geomspace(1.0, 1e-6, 50))
    assert training_checks("ddm", good, falling, settings) == []
    assert training_checks("ddm", {**good, "omega": 0.8}, falling, settings)[0].startswith(
        "ETHZ validation RMSE above the bar: omega"
    )
    assert training_checks("dpm", {**good, "omega": 4.0}, falling, settings) == []  # no bar
    flat = [0.7, 0.3, 0.2, 0.17, 0.163] + [0.163] * 395  # DDM's seed-1 training
    assert "stalled" in training_checks("ddm", good, flat, settings)[0]
    assert training_checks("ddm", good, flat[:5], settings) == []  # too short to tell
    flagged = outliers({0: 1e-7, 1: 2e-7, 2: 5e-5}, 10)
    assert list(flagged) == [2] and "10 × the replicates' median 2e-07" in flagged[2]
    assert outliers({0: 1e-7, 1: 5e-5}, 10) == {}  # two replicates: no median to speak of
    table = pd.DataFrame([{"model": "ddm", **{f"val_rmse_{k}": v for k, v in good.items()}}])
    health = training_health(
        {0: table, 1: table, 2: table},
        {(r, "ddm"): pd.DataFrame({"train_loss": flat if r == 1 else falling}) for r in range(3)},
        {(0, "ddm"): 1e-7, (1, "ddm"): 0.16, (2, "ddm"): 2e-7},
        settings,
    )
    assert health["trained"].tolist() == [True, False, True]
    assert "stalled" in health["reason"][1] and "median" in health["reason"][1]


def test_the_papers_study_runs_for_every_replicate_and_the_others_for_replicate_0() -> None:
    config = {"seeds": 2, "studies": {
        "learned": {"plants": ["epm"], "controllers": ["pid"], "replicates": "all"},
        "truth": {"plants": ["truth"], "internal": ["epm", "truth"], "controllers": ["nmpc"],
                  "replicates": [0, 1]},
    }}  # fmt: skip
    runs = study_runs(config, ["0"], lambda c: c == "nmpc", replicates=3)
    learned = [r for r in runs if r.study == "learned"]
    assert sorted({r.replicate for r in learned}) == [0, 1, 2] and len(learned) == 6
    computed = canonical(runs)
    # the truth plant with the true model uses no trained network: computed once, replicate 0's
    true = RunId("truth", "truth", "truth", "nmpc", "0", 1, replicate=1)
    assert computed[true] == RunId("truth", "truth", "truth", "nmpc", "0", 1, replicate=0)
    learned_internal = RunId("truth", "truth", "epm", "nmpc", "0", 1, replicate=1)
    assert computed[learned_internal] == learned_internal
    folder = learned_internal.folder("results/runs")
    assert str(folder) == "results/runs/truth/rep1/truth/epm/nmpc/eta0/seed1"
    assert RunId.parse(folder / "metrics.json") == learned_internal


def test_a_row_of_replicate_0_alone_holds_everywhere_it_was_measured() -> None:
    from cape.study.scorecard import counts

    table = pd.DataFrame(
        {
            "verdict rep0": [HOLDS, HOLDS, HOLDS],
            "verdict rep1": ["not run", INCONCLUSIVE, HOLDS],
            "verdict": [HOLDS, HOLDS, HOLDS],
        }
    )
    assert counts(table)["hold in every replicate"] == 2  # the first and the last
