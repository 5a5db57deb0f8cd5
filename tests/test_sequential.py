"""The staged question (SPEC §10, revision 6): the group-sequential test's boundaries against
Student's t, its equivalence test against statsmodels' TOST, hand-made looks, and its error
rates over every look by simulation at this study's sizes (R₁ = 3, cap 20, 15 rows)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from cape.errors import CapeError
from cape.specs.study import StudySpec
from cape.study.question.looks import RowState, evaluate, next_draws
from cape.study.question.plan import Plan, QuestionSettings, run_overrides, stage_runs
from cape.study.stats import sequential_calibration as calib
from cape.study.stats.sequential import (
    CONTRADICTED,
    EQUIVALENT,
    HOLDS,
    INCONCLUSIVE,
    OPEN,
    Design,
    boundaries,
    look,
    payoff_seeds,
    seeds_per_draw,
    variance_components,
)

STUDY = Design((3, 6, 10, 15, 20), rows=15)
"""The question's design: looks at 3 … 20 draws per model, 15 rows, family-wise α 0.05."""


@pytest.mark.parametrize("n", [3, 5, 10])
def test_one_look_is_students_t(n: int) -> None:
    """With one look and one row the boundaries are t quantiles: two-sided 97.5 %, one-sided 95 %
    (seeded Monte Carlo: within 2 % of scipy's)."""
    two, one = boundaries((n,), 0.05, 2.0, True)[0], boundaries((n,), 0.05, 2.0, False)[0]
    assert two == pytest.approx(stats.t.ppf(0.975, n - 1), rel=0.02)
    assert one == pytest.approx(stats.t.ppf(0.95, n - 1), rel=0.02)


def test_one_look_equivalence_is_statsmodels_tost() -> None:
    """At one look the equivalence decision is the two one-sided tests: for 200 random samples
    it agrees with statsmodels' ``ttost_mean`` at 5 % wherever their p-value is not within
    Monte Carlo error of 5 %."""
    from statsmodels.stats.weightstats import DescrStatsW

    design = Design((6,), rows=1)
    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(200):
        x = rng.normal(rng.uniform(-1, 1), 0.5, size=6)
        p = DescrStatsW(x).ttost_mean(-1.0, 1.0)[0]
        if abs(p - 0.05) < 0.005:
            continue
        said = look(list(x), design, 1.0, -1.0, last=True).decision
        assert (said == EQUIVALENT) == (p < 0.05) or said in (HOLDS, CONTRADICTED)
        checked += 1
    assert checked > 150


def test_the_boundaries_fall_as_draws_come() -> None:
    """Spending α·(n/20)² over 3, 6, 10, 15, 20 draws with α/15 per row: almost nothing at three
    draws (the t-quantile of 2 degrees of freedom is huge), most near the cap; every boundary at
    the cap is above the fixed-sample t quantile at the same α (the price of the looks)."""
    c, e = STUDY.difference, STUDY.equivalence
    assert all(a > b for a, b in itertools.pairwise(c))
    assert all(a > b for a, b in itertools.pairwise(e))
    assert c[-1] > stats.t.ppf(1 - STUDY.per_row / 2, 19)
    assert e[-1] > stats.t.ppf(1 - STUDY.per_row, 19)
    assert c[0] > 30


def test_a_look_decides_by_hand() -> None:
    """Hand-made draws' effects at one look of 5 draws, one row (t 97.5 % = 2.776, 95 % = 2.132):
    mean 1, sd 0.158, t = 14.1: holds when the side tested is +1, contradicted when −1; mean
    0.02 with a small spread inside ±0.5: equivalent (without a margin: inconclusive); a spread
    too wide for both: open before the last look, inconclusive at it; no spread: open."""
    d = Design((5,), rows=1)
    clear = [0.8, 0.9, 1.0, 1.1, 1.2]
    assert look(clear, d, None, 1.0, last=True).decision == HOLDS
    assert look(clear, d, None, -1.0, last=True).decision == CONTRADICTED
    small = [0.0, 0.05, -0.03, 0.04, 0.04]
    assert look(small, d, 0.5, 1.0, last=True).decision == EQUIVALENT
    assert look(small, d, None, 1.0, last=True).decision == INCONCLUSIVE  # no margin
    wide = [-2.0, 1.5, 0.3, -0.8, 1.1]
    assert look(wide, d, 0.5, 1.0, last=False).decision == OPEN
    assert look(wide, d, 0.5, 1.0, last=True).decision == INCONCLUSIVE
    flat = look([1.0] * 5, d, 0.5, 1.0)
    assert flat.decision == OPEN and flat.why == "no spread over 5 draws"
    one = look(clear, d, None, 1.0, last=True)
    se = np.std(clear, ddof=1) / math.sqrt(5)
    assert one.low == pytest.approx(1.0 - d.difference[0] * se)
    with pytest.raises(ValueError, match="no look"):
        look(clear[:4], d, None, 1.0)


def test_variance_components_and_the_two_stage_optimum_by_hand() -> None:
    """Draws × seeds [[1, 3], [5, 7]]: σ²_within = 2, the draws' means 2 and 6 vary by 8, so
    σ²_between = 8 − 2/2 = 7. With a draw costing 28 seeds' runs the optimum is √(28·2/7) =
    2.83 → 3 seeds; draws that do not differ take the most; the bounds hold."""
    between, within = variance_components(np.array([[[1.0, 3.0], [5.0, 7.0]]]))
    assert between[0] == pytest.approx(7.0) and within[0] == pytest.approx(2.0)
    assert int(seeds_per_draw(7.0, 2.0, 28.0, 2, 5)) == 3
    assert int(seeds_per_draw(0.0, 2.0, 28.0, 2, 5)) == 5
    assert int(seeds_per_draw(100.0, 0.01, 28.0, 2, 5)) == 2


# --- the error rates over every look, by simulation (4000 rows a case, seeded) -------------

RATIOS = (0.2, 1.0, 10.0)
"""σ_between / σ_within, as in the interval's calibration (tests/test_verdicts.py)."""


@pytest.mark.parametrize("law", calib.LAWS)
@pytest.mark.parametrize("ratio", RATIOS)
def test_no_effect_is_rarely_decided_over_all_looks(law: str, ratio: float) -> None:
    """With no true effect a row is decided (holds or contradicted) at any of the five looks in
    at most 5 % of rows (the acceptance); within Monte Carlo error of its own α/15 where the
    effect is symmetric, within twice that where the two models differ in shape (measured
    0.50 % at most, docs/question.md)."""
    rate = calib.false_verdict_rate(STUDY, law, ratio, margin=ratio)
    assert rate <= 0.05
    nominal = STUDY.per_row * (2 if law == "unequal" else 1)
    assert rate <= nominal + 3 * math.sqrt(nominal / 4000) + 0.001


@pytest.mark.parametrize("law", ("normal", "skewed", "unequal"))
@pytest.mark.parametrize("ratio", RATIOS)
def test_an_effect_at_the_margin_is_rarely_called_equivalent(law: str, ratio: float) -> None:
    """With a true effect equal to the margin (1 σ_between, or 1 σ_within where the draws
    differ less) a row is called ``equivalent`` in at most 5 % of rows."""
    margin = max(ratio, 1.0)
    assert calib.false_equivalence_rate(STUDY, law, margin, ratio) <= 0.05


def test_failure_counts_at_the_margin_are_rarely_called_equivalent() -> None:
    """Integer failure counts, one failure per seed more for one model (the margin)."""
    assert calib.false_equivalence_rate(STUDY, "failures", 1.0) <= 0.05


@pytest.mark.parametrize("law", calib.LAWS)
def test_the_family_error_holds_with_some_rows_null(law: str) -> None:
    """Families of the question's 15 rows, 8 with no effect and 7 with an effect of 2 σ_between
    (margin 1 σ_between): at most 5 % of families have any false verdict over all looks."""
    assert calib.family_error(STUDY, law, 8, 7, 2.0, 1.0, 1.0, trials=1000) <= 0.05


@pytest.mark.parametrize("law", ("normal", "skewed", "unequal"))
def test_an_effect_of_two_between_draw_sds_is_found_with_fewer_draws(law: str) -> None:
    """A true effect of 2 σ_between where the draws differ as much as the seeds: decided on its
    side in at least 95 % of rows, using on average fewer draws than the cap (measured: about
    11 of 20 per model, docs/question.md)."""
    power, used = calib.power(STUDY, law, 2.0, 1.0)
    assert power >= 0.95
    assert used < 15


def test_the_payoff_rule_by_hand() -> None:
    """One model buying 4 draws at 10 s each plus 1 s a seed: a chance that grows as n/10 pays
    best at the most seeds ((n/10)/(4·(10 + n)) grows with n); a chance that no seed changes
    pays best at the least; two rows sum their chances; nothing bought: the least."""
    buying = np.array([[True]])
    cost = np.array([10.0]), np.array([1.0])
    grows = lambda n: np.array([[min(1.0, n / 10)]])  # noqa: E731
    flat = lambda n: np.array([[0.5]])  # noqa: E731
    assert int(payoff_seeds(grows, buying, 4, *cost, 2, 8)[0]) == 8
    assert int(payoff_seeds(flat, buying, 4, *cost, 2, 8)[0]) == 2
    assert int(payoff_seeds(flat, np.array([[False]]), 4, *cost, 2, 8)[0]) == 2


def test_later_draws_get_the_seeds_that_pay() -> None:
    """Draws that differ far more than seeds need few seeds: the simulated procedure chooses
    the least (2) for most rows; where the draws do not differ at all, a fair share of rows
    buy the most seeds the costs allow (15 at a draw costing 15 seeds)."""
    design = Design(STUDY.looks, 15, futility=0.05)
    out = calib.simulate(calib.one_row("normal", 0.0, 10.0, 1.0), design, calib.Procedure(),
                         trials=500)  # fmt: skip
    assert np.median(out.seeds[:, 0]) == 2
    out = calib.simulate(calib.one_row("normal", 0.5, 0.0, 1.0), design, calib.Procedure(),
                         trials=500)  # fmt: skip
    assert (out.seeds[:, 0] == 15).mean() > 0.2


def test_look_and_simulate_decide_the_same_values_alike() -> None:
    """``look`` (what `cape question` decides on one row) and ``simulate`` (the calibration's
    thousands of rows at once) share one rule, ``decide``: replayed look by look through
    ``look``, the very draws' effects ``simulate`` drew give its decision, the draws it used and
    its repeated interval, trial by trial (fixed seeds, no futility, no variance floor)."""
    design = Design((3, 6, 10), rows=1)
    rows = calib.one_row("normal", 0.6, 1.0, 0.5)
    procedure = calib.Procedure(rule="fixed", first=4, floor=False)
    out = calib.simulate(rows, design, procedure, trials=60, seed=7)
    width = max(procedure.first, procedure.most)  # the seeds simulate draws for each draw
    values = calib.seed_values(rows, np.random.default_rng(7), 60, design.cap, width)
    effects = values[:, 0, :, : procedure.first].mean(axis=-1)  # trials × draws: over its seeds
    decided = set()
    for t in range(60):
        for n in design.looks:
            one = look(effects[t, :n], design, rows[0].margin, rows[0].side, n == design.cap)
            if one.decision != OPEN:
                break
        assert (one.decision, n) == (out.decision[t, 0], out.used[t, 0]), t
        assert one.low == pytest.approx(out.low[t, 0]) and one.high == pytest.approx(out.high[t, 0])
        decided.add(one.decision)
    assert len(decided) >= 2, decided  # the values reach more than one decision


# --- the question's plan ---------------------------------------------------------------------


def _config(models=("epm", "ddm", "dpm"), stages=(3, 6, 10)) -> dict:
    from cape.config import load_config

    config = load_config()
    config["question"]["models"] = list(models)
    config["question"]["stages"] = list(stages)
    return config


def test_the_question_has_five_metrics_for_every_pair() -> None:
    settings = QuestionSettings.from_config(_config())
    rows = settings.rows()
    assert len(rows) == 15 and settings.design().rows == 15
    assert {r.comparison for r in rows} >= {"EPM − DDM", "EPM vs DPM", "DDM vs DPM"}
    margins = {r.metric: r.margin for r in rows}  # relative ones on the log-ratio scale
    assert margins["lap_time_penalised"] == 0.2 and margins["failures"] == 1.0
    assert margins["mean_abs_ex_penalised"] == pytest.approx(100 * math.log(1.1))
    assert margins["mean_speed"] == pytest.approx(100 * math.log(1.03))


def test_a_question_with_an_unknown_model_names_the_field_and_the_fix() -> None:
    with pytest.raises(CapeError, match=r"question\.models.*ddm_tuned is not one.*question\.yaml"):
        QuestionSettings.from_config(_config(("epm", "ddm_tuned")))
    with pytest.raises(CapeError, match=r"question\.stages.*increase"):
        QuestionSettings.from_config(_config(stages=(6, 3)))


def test_draws_are_added_only_to_the_models_of_open_rows() -> None:
    """EPM − DDM settled, EPM − DPM and DDM − DPM open: all three get more draws; with only the
    rows without DDM open, DDM keeps its three."""
    settings = QuestionSettings.from_config(_config())
    states = [RowState(r) for r in settings.rows()]
    runs = pd.DataFrame(
        columns=["model", "replicate", "seed", "controller", "eta", "success", "lap_time_penalised"]
    )
    for s in states:  # every row decided but those of EPM against DPM
        if s.row.models != ("epm", "dpm"):
            s.looks.append(look([0.1, 0.12, 0.11], Design((3,), 1), 1.0, 1.0, True))
    assert sum(s.settled for s in states) == 10
    nxt = next_draws(states, {"epm": 3, "ddm": 3, "dpm": 3}, 6)
    assert nxt == {"epm": 6, "ddm": 3, "dpm": 6}
    evaluate(runs, states, settings.design(), 1)  # no runs: inconclusive for good, said why
    assert all(s.decision == INCONCLUSIVE for s in states if not s.settled)
    assert states[1].looks[-1].why.startswith("0 of 6 draws have a value")
    assert next_draws(states, nxt, 10) == nxt  # rows done for good buy no draws


def test_a_stage_runs_only_the_questions_nmpc_runs() -> None:
    """Stage runs: per model its draws × 3 NMPCs × 11 η × seeds (5 for the first three draws,
    2 after); the overrides keep the paper's study at its own draws and add the models to the
    ground-truth study."""
    config = _config()
    settings = QuestionSettings.from_config(config)
    plan = Plan({"epm": 6, "ddm": 3, "dpm": 6}, (5, 5, 5, 2, 2, 2))
    runs = stage_runs(settings, plan)
    per_model = pd.Series([r.internal for r in runs]).value_counts()
    assert per_model["epm"] == 3 * 11 * (3 * 5 + 3 * 2)
    assert per_model["ddm"] == 3 * 11 * 3 * 5
    assert {r.controller for r in runs} == {"nmpc", "anmpc", "rnmpc"}
    assert {r.plant for r in runs} == {"truth"}
    overrides = run_overrides(StudySpec.from_config(config), settings, plan)
    assert overrides["training"]["replicates"] == 6
    assert overrides["study"]["studies"]["learned"] == {"replicates": [0, 1, 2]}
    assert overrides["question"]["plan"]["draws"] == {"epm": 6, "ddm": 3, "dpm": 6}
    # one cap for every stage, the last one's: twice its 10 draws, or a fixed cap grown alike
    assert overrides["training"]["max_trainings"] == 20
    config["training"]["max_trainings"] = 4  # 4 × 10/3
    overrides = run_overrides(StudySpec.from_config(config), settings, plan)
    assert overrides["training"]["max_trainings"] == 14


def test_the_questions_ddm_recipe_is_the_examples() -> None:
    """config/question.yaml's `ddm_tuned` is config/examples/ddm_tuned.yaml's, key for key, so
    a training made with either is the other's (docs/models.md); both are the authors' recipe."""
    import yaml

    from cape.config import REPO_ROOT

    def entry(name: str) -> dict:
        return yaml.safe_load((REPO_ROOT / "config" / name).read_text())["models"]["ddm_tuned"]

    assert entry("question.yaml") == entry("examples/ddm_tuned.yaml")
    assert entry("question.yaml")["train"] == {"lr": 1.44e-4, "batch_size": 2, "epochs": 400}


def test_the_workflows_question_module_stays_light() -> None:
    """Snakemake imports cape.study.question.plan whenever it reads the Snakefile (in every job
    of a SLURM group too): it must not pull in pandas or SciPy (about 1.6 s a process)."""
    import subprocess
    import sys

    code = (
        "import sys, cape.study.question.plan; "
        "print(sorted({'pandas', 'scipy'} & set(sys.modules)))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_the_projection_to_the_cap_by_hand() -> None:
    """One open row of models a and b at three draws, the cap at six: three more trainings each
    (100 s for a, 50 s for b) list-scheduled on 2 slots end at 250 s; then 6 draws × 2 seeds ×
    10 s of runs over 2 slots, 60 s: 310 s. At most 3 × (100 + 20) + 3 × (50 + 20) = 570 s CPU."""
    from cape.study.claims.declared import question_claims
    from cape.study.question.plan import Row
    from cape.study.question.report import Cost, projected_wall, remaining

    claim = question_claims(["a", "b"])[0]
    states = [RowState(Row(claim, claim.pairs[0], None))]
    settings = QuestionSettings(("a", "b"), (3, 6), 0.05, 2.0, {}, "truth", ("0",), 5, 2)
    cost = Cost(trainings={"a": [300.0], "b": [150.0]}, draws={"a": 3, "b": 3}, runs_s=110.0,
                runs=33, etas=1)  # fmt: skip
    assert cost.per_seed() == pytest.approx(10.0)
    draws = {"a": 3, "b": 3}
    assert projected_wall(states, settings, draws, cost, 2, 2) == pytest.approx(310.0)
    assert remaining(states, settings, draws, cost, 2) == pytest.approx(570.0)
