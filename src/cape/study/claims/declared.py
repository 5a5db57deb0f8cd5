"""The claims of SPEC §10 as data: one declaration each, evaluated by cape.study.claims.scorecard.

A closed-loop claim names the runs it reads (``select``), the per-run value (``metric``, or
``FAILURES``), how a model's runs of one seed become one number (``per_seed``), the effect of
model a against b (``DIFFERENCE`` or ``RELATIVE``), its pairwise comparisons with the paper's
effect (whose sign is the claim's side) and the measured causes a row that does not hold can
cite. A model claim reads one column of table 1 or 4 per training draw. The best bicycle
controller is one deterministic comparison per model. A new claim is one declaration here plus
its test.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from cape import paper
from cape.layout.names import NMPCS

FAILURES = "failures"
"""A closed-loop claim's metric: the runs that failed (summed per seed with ``per_seed="sum"``)."""


@dataclass(frozen=True)
class Effect:
    """How model a's per-seed values compare with model b's: the function, the unit printed
    after a value, and how the comparison is named (``a − b`` or ``a vs b``)."""

    of: Callable[[pd.Series, pd.Series], pd.Series]
    unit: str
    joiner: str


DIFFERENCE = Effect(lambda a, b: a - b, "", " − ")
RELATIVE = Effect(lambda a, b: 100 * (a - b) / b, " %", " vs ")
LOG_RATIO = Effect(lambda a, b: 100 * np.log(a / b), " % (100·ln a/b)", " vs ")
"""The question's relative effect: 100·ln(a/b), about the relative difference for small ones.
Unlike (a − b)/b it is antisymmetric, so two exchangeable models have no effect on average
(the mean of (a − b)/b over independent draws is positive: Jensen)."""


@dataclass(frozen=True)
class Pair:
    """One comparison of a claim: model ``a`` against ``b``, the paper's effect (its sign is
    the paper's side) and how the paper's value is printed."""

    a: str
    b: str
    paper_effect: float
    paper_text: str


@dataclass(frozen=True)
class Context:
    """What the cause texts draw on, all measured: the reference's ideal lap time, the
    trainings that failed (replicate → model → reason), table 4 per replicate."""

    ideal_lap_time: float | None = None
    failed: Mapping[int, Mapping[str, str]] = field(default_factory=dict)
    openloop: Mapping[int, pd.DataFrame] = field(default_factory=dict)


Cause = Callable[[Context, Pair], str]
"""A measured cause a row that does not hold can cite ("" when it has nothing to say)."""


@dataclass(frozen=True)
class ClosedLoopClaim:
    """A claim about the paper's closed-loop runs (``name``: its label; ``{cells}`` is
    replaced by the number of (controller, η) cells it reads)."""

    name: str
    select: Selection
    metric: str
    pairs: tuple[Pair, ...]
    effect: Effect = DIFFERENCE
    unit: str = ""
    per_seed: str = "mean"
    causes: tuple[Cause, ...] = ()
    setting: str = "paper"
    """Whose runs it reads: ``"paper"`` (the paper's study, ``study.paper``) or
    ``"ground-truth plant"`` (the ground-truth study, ``study.ground_truth``: the simulated car
    with its true parameters, SPEC §1; CAPE's own claims, no paper value)."""


PAPER_SETTING = "paper"
GROUND_TRUTH = "ground-truth plant"


@dataclass(frozen=True)
class ModelClaim:
    """A claim about table 1 (``complexity``) or table 4 (``openloop``): one value per model
    and training draw; ``exact``: the architecture's (holds or contradicted, no interval)."""

    name: str
    column: str
    table: str
    exact: bool
    pairs: tuple[Pair, ...]
    causes: tuple[Cause, ...] = ()


@dataclass(frozen=True)
class BicycleClaim:
    """The best fixed-parameter bicycle controller per model (table 5 against the paper)."""

    name: str
    best: Mapping[str, Mapping[str, float | str]]


def ordering(values: Mapping[str, float], unit: str = "") -> tuple[Pair, ...]:
    """Every pair of an ordering by the paper's values (lowest first), a − b with a below b."""
    order = sorted(values, key=values.__getitem__)
    return tuple(
        Pair(a, b, values[a] - values[b], _paper_difference(values, a, b, unit))
        for a, b in itertools.combinations(order, 2)
    )


def against(model: str, values: Mapping[str, float], unit: str = "") -> tuple[Pair, ...]:
    """``model`` against each other model of ``values``, in their order."""
    return tuple(
        Pair(
            model,
            other,
            values[model] - values[other],
            _paper_difference(values, model, other, unit),
        )
        for other in values
        if other != model
    )


def relative(model: str, percents: Mapping[str, float]) -> tuple[Pair, ...]:
    """``model``'s relative difference against each other model, as the paper prints it."""
    return tuple(Pair(model, other, value, f"{value:+.3g} %") for other, value in percents.items())


def _paper_difference(values: Mapping[str, float], a: str, b: str, unit: str) -> str:
    return (
        f"{values[a] - values[b]:.3g}{unit} ({a.upper()} {values[a]:g}, {b.upper()} {values[b]:g})"
    )


@dataclass(frozen=True)
class Selection:
    """The runs a claim reads: ``what`` names them in a row that cannot be evaluated."""

    what: str
    keep: Callable[[pd.DataFrame], pd.Series]

    def __call__(self, runs: pd.DataFrame) -> pd.DataFrame:
        return runs[self.keep(runs)]


def controllers(names: Sequence[str]) -> Selection:
    """The runs of these controllers."""
    return Selection(
        f"runs of {', '.join(names)}", lambda runs: runs["controller"].isin(list(names))
    )


def at_eta(eta: float) -> Selection:
    """The runs at one disturbance level."""
    return Selection(f"runs at η = {eta:g}", lambda runs: runs["eta"] == eta)


def both(first: Selection, second: Selection) -> Selection:
    """The runs both selections keep."""
    return Selection(
        f"{first.what} among the {second.what}", lambda runs: first.keep(runs) & second.keep(runs)
    )


def own(pairs: tuple[Pair, ...], unit: str = "") -> tuple[Pair, ...]:
    """The same comparisons as CAPE's own question: no paper value; the side tested is the
    paper's on its learned plants (does its ordering carry over to the ground-truth plant?)."""
    return tuple(
        Pair(
            p.a,
            p.b,
            p.paper_effect,
            f"none (CAPE's own); tested: {p.a.upper()} {'<' if p.paper_effect < 0 else '>'} "
            f"{p.b.upper()}, the paper's side on its learned plants",
        )
        for p in pairs
    )


def _relative_between(model: str, other: str, percents: Mapping[str, float]) -> float:
    """``model`` against ``other`` in %, from EPM's relative differences against both."""
    ratio = (1 + percents[other] / 100) / (1 + percents[model] / 100)  # model/other
    return 100 * (ratio - 1)


def lap_time_bound(context: Context, pair: Pair) -> str:
    """Why our lap times are not the paper's: the reference's own ideal lap."""
    if context.ideal_lap_time is None:
        return ""
    return (
        f"our laps are bounded by the reference's ideal lap, {context.ideal_lap_time:.2f} s at "
        "its speed profile; the paper's 5.6–5.8 s lie below it"
    )


def machine(context: Context, pair: Pair) -> str:
    """Inference times are the machine's and the implementation's."""
    return (
        "hardware and implementation: timed on this CPU with CAPE's compiled Φ, one window "
        "at a time; the paper's times come from another machine"
    )


def extrapolation(component: str) -> Cause:
    """ETHZMobil's error over the ETHZ validation error, per model: how far the held-out
    track lies outside the training data for this component."""

    def cause(context: Context, pair: Pair) -> str:
        ratios = []
        for model in (pair.a, pair.b):
            values = [
                float(t.set_index("model").loc[model, f"test_rmse_{component}"])
                / float(t.set_index("model").loc[model, f"val_rmse_{component}"])
                for t in context.openloop.values()
                if model in set(t["model"]) and f"val_rmse_{component}" in t
            ]
            if values:
                ratios.append(f"{model.upper()} {sum(values) / len(values):.1f}×")
        if not ratios:
            return ""
        return (
            "ETHZMobil extrapolation: the ETHZMobil error over the ETHZ validation error is "
            + ", ".join(ratios)
            + " (ETHZMobil's slip lies outside the training data's, SPEC §4.2)"
        )

    return cause


def _complexity(column: str) -> dict[str, float]:
    return {m: values[column] for m, values in paper.COMPLEXITY.items()}


def _rmse(component: str) -> dict[str, float]:
    return {m: values[component] for m, values in paper.OPENLOOP_RMSE.items()}


def _model_claim(name: str, column: str, exact: bool, causes: tuple[Cause, ...] = ()) -> ModelClaim:
    if column.startswith("test_rmse_"):
        table, values = "openloop", _rmse(column.removeprefix("test_rmse_"))
    else:
        table, values = "complexity", _complexity(column)
    order = " < ".join(m.upper() for m in sorted(values, key=values.__getitem__))
    return ModelClaim(f"{name}: {order}", column, table, exact, ordering(values), causes)


CLOSED_LOOP: tuple[ClosedLoopClaim, ...] = (
    ClosedLoopClaim(
        "adaptive NMPC lap time, penalised, mean over η (s): EPM < DDM < DPM",
        controllers(["anmpc"]),
        "lap_time_penalised",
        ordering(paper.ADAPTIVE_LAP_TIME, " s"),
        unit=" s",
        causes=(lap_time_bound,),
    ),
    *(
        ClosedLoopClaim(
            f"η = 1, mean over controllers: {metric} (%)",
            at_eta(1.0),
            metric,
            relative("epm", anchors),
            effect=RELATIVE,
            unit=" %",
        )
        for metric, anchors in paper.ETA1_RELATIVE.items()
    ),
    ClosedLoopClaim(
        "NMPC-family failures of {cells} runs: EPM fewest",
        controllers(NMPCS),
        FAILURES,
        against("epm", {m: paper.NMPC_FAILURES[m] for m in ("epm", "ddm", "dpm")}),
        per_seed="sum",
    ),
)
"""The paper's closed-loop claims (SPEC §10) on its main study."""

GROUND_TRUTH_CLAIMS: tuple[ClosedLoopClaim, ...] = (
    ClosedLoopClaim(
        "ground-truth plant: adaptive NMPC lap time, penalised, mean over η (s), by its internal "
        "model",
        controllers(["anmpc"]),
        "lap_time_penalised",
        own(ordering(paper.ADAPTIVE_LAP_TIME, " s")),
        unit=" s",
        causes=(lap_time_bound,),
        setting=GROUND_TRUTH,
    ),
    *(
        ClosedLoopClaim(
            f"ground-truth plant: η = 1, mean over the NMPCs: {metric} (%), by their internal "
            "model",
            both(at_eta(1.0), controllers(NMPCS)),
            metric,
            own(
                (
                    *relative("epm", anchors),
                    Pair("ddm", "dpm", _relative_between("ddm", "dpm", anchors), ""),
                )
            ),
            effect=RELATIVE,
            unit=" %",
            setting=GROUND_TRUTH,
        )
        for metric, anchors in paper.ETA1_RELATIVE.items()
    ),
    ClosedLoopClaim(
        "ground-truth plant: NMPC-family failures of {cells} runs, by their internal model",
        controllers(NMPCS),
        FAILURES,
        own(ordering({m: paper.NMPC_FAILURES[m] for m in ("epm", "ddm", "dpm")})),
        per_seed="sum",
        setting=GROUND_TRUTH,
    ),
)
"""CAPE's own claims (which model drives the ground-truth plant best): the paper's comparisons
on the ground-truth plant, each learned model as the NMPCs' internal model; EPM against DDM and
DPM, and DDM against DPM."""

BICYCLE = BicycleClaim("best bicycle controller (replicate 0)", paper.BEST_BICYCLE)
"""The best fixed-parameter bicycle controller: replicate 0's bicycle study."""

MODEL: tuple[ModelClaim, ...] = (
    _model_claim("model complexity: parameters (M)", "params_M", True),
    _model_claim("model complexity: size (MB)", "size_MB", True),
    _model_claim("model complexity: FLOPs (M)", "flops_M", True),
    _model_claim("model complexity: inference (ms)", "inference_ms", False, (machine,)),
    *(
        _model_claim(
            f"open-loop RMSE {label} (ETHZMobil)",
            f"test_rmse_{component}",
            False,
            (extrapolation(component),),
        )
        for component, label in (("vx", "vx"), ("vy", "vy"), ("omega", "ω"))
    ),
)
"""Model complexity (table 1) and open-loop error (table 4), in the paper's order."""


LOWER_IS_BETTER = {
    "lap_time_penalised": True,
    "mean_abs_ex_penalised": True,
    "mean_abs_ey_penalised": True,
    "mean_speed": False,
    FAILURES: True,
}
"""The question's metrics, and which way is better on each."""


def _better(models: Sequence[str], metric: str) -> tuple[Pair, ...]:
    """Every pair (a, b) of ``models`` in their order, tested as a better than b on
    ``metric``: the side is the sign a better a gives the effect a − b (or a vs b)."""
    side = -1.0 if LOWER_IS_BETTER[metric] else 1.0
    sign = "<" if side < 0 else ">"
    return tuple(
        Pair(a, b, side, f"none (the question's); tested: {a.upper()} {sign} {b.upper()}")
        for a, b in itertools.combinations(models, 2)
    )


def question_claims(models: Sequence[str]) -> tuple[ClosedLoopClaim, ...]:
    """The ground-truth question's claims (``cape question``): the scorecard's five ground-truth
    comparisons (the adaptive NMPC's penalised lap time over η; the NMPCs' e_x, e_y and speed at
    η = 1 as log-ratios, ``LOG_RATIO``; their failures per seed) for every pair of ``models``,
    each tested as the earlier model better than the later (for EPM, DDM, DPM: the paper's
    side, as in ``GROUND_TRUTH_CLAIMS``)."""
    nmpcs_at_1 = both(at_eta(1.0), controllers(NMPCS))
    return (
        ClosedLoopClaim(
            "adaptive NMPC lap time, penalised, mean over η (s)",
            controllers(["anmpc"]),
            "lap_time_penalised",
            _better(models, "lap_time_penalised"),
            unit=" s",
            setting=GROUND_TRUTH,
        ),
        *(
            ClosedLoopClaim(
                f"η = 1, mean over the NMPCs: {metric} (100·ln a/b, %)",
                nmpcs_at_1,
                metric,
                _better(models, metric),
                effect=LOG_RATIO,
                unit=" %",
                setting=GROUND_TRUTH,
            )
            for metric in ("mean_abs_ex_penalised", "mean_abs_ey_penalised", "mean_speed")
        ),
        ClosedLoopClaim(
            "NMPC-family failures per seed (3 NMPCs × every η)",
            controllers(NMPCS),
            FAILURES,
            _better(models, FAILURES),
            per_seed="sum",
            setting=GROUND_TRUTH,
        ),
    )
