"""The ground-truth question in stages (SPEC §10, revision 6): its rows, what a look decides,
which models get more draws, and which runs a stage needs.

The question compares every pair of ``question.models`` (claimed best first) on the five
closed-loop metrics of ``cape.study.claims.question_claims``, each learned model inside the
NMPCs on the ground-truth plant. Stage k gives every model of a row still open ``stages[k]``
trained draws (the others keep theirs), and each row is decided by the group-sequential test of
``cape.study.sequential`` at the look of its draws. The first stage's draws have the study's
seeds; later draws the two-stage optimum from the first look's variance components
(``later_seeds``). ``cape question`` (cape/cli/question.py) drives Snakemake through the stages;
this module is the part of it that needs no Snakemake.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from cape.errors import CapeError
from cape.layout.names import TRUTH
from cape.layout.runs import RunId
from cape.study.claims import LOG_RATIO, NMPCS, ClosedLoopClaim, Pair, question_claims
from cape.study.scorecard import pair_effects, per_seed
from cape.study.sequential import INCONCLUSIVE, OPEN, SETTLED, Design, Look, look, seeds_per_draw
from cape.study.sequential import variance_components as components


@dataclass(frozen=True)
class QuestionSettings:
    """What the question reads from the config: the models (best claimed first), the looks'
    draws per model, the family's α and the spending exponent, the margins by metric, the
    ground-truth study's name, η grid and seeds, and the least seeds a later draw gets."""

    models: tuple[str, ...]
    stages: tuple[int, ...]
    alpha: float
    spending: float
    margins: Mapping[str, float]
    study: str
    etas: tuple[str, ...]
    seeds: int
    least_seeds: int

    @classmethod
    def from_config(cls, config: Mapping[str, Any], source: str = "config") -> QuestionSettings:
        """The settings, each cross-field problem one ``CapeError`` naming the key and fix."""
        q = config.get("question") or {}
        study = config["study"].get("ground_truth")
        studies = config["study"]["studies"]
        if not study or study not in studies:
            raise CapeError(
                f"{source}: `study.ground_truth` names no study of `study.studies` "
                f"({study!r}); the question runs on the ground-truth study: set it to one"
            )
        models = tuple(q.get("models") or ())
        unknown = [m for m in models if m not in config["models"]]
        if len(models) < 2 or unknown:
            raise CapeError(
                f"{source}: field `question.models` must name two or more models of `models`"
                + (f"; {', '.join(unknown)} is not one" if unknown else "")
                + (
                    " (DDM's tuned recipe is config/question.yaml's: merge it)"
                    if "ddm_tuned" in unknown
                    else ""
                )
            )
        stages = tuple(int(s) for s in q.get("stages") or ())
        if not stages or any(b <= a for a, b in itertools.pairwise(stages)):
            raise CapeError(f"{source}: field `question.stages` must increase: {list(stages)}")
        missing = [c for c in NMPCS if c not in config["controllers"]]
        if missing:
            raise CapeError(
                f"{source}: the question reads the NMPCs' runs, and `controllers` lacks "
                f"{', '.join(missing)}; add them back"
            )
        grid = studies[study]
        etas = tuple(grid.get("eta") or config["disturbances"]["eta"])
        seeds = int(config["study"]["seeds"])
        least = int((q.get("seeds") or {}).get("least", 2))
        return cls(
            models,
            stages,
            float(q.get("alpha", 0.05)),
            float(q.get("spending", 2.0)),
            {
                str(k): float(v)
                for k, v in (config.get("scorecard", {}).get("margins") or {}).items()
            },
            study,
            etas,
            seeds,
            min(least, seeds),
        )

    def claims(self) -> tuple[ClosedLoopClaim, ...]:
        return question_claims(self.models)

    def rows(self) -> list[Row]:
        """Every (claim, pair), with its metric's margin; a relative margin m % becomes
        100·ln(1 + m/100) on the log-ratio scale (a/b within [1/(1 + m), 1 + m])."""
        rows = []
        for claim in self.claims():
            margin = self.margins.get(claim.metric)
            if margin is not None and claim.effect is LOG_RATIO:
                margin = 100 * math.log1p(margin / 100)
            rows += [Row(claim, pair, margin) for pair in claim.pairs]
        return rows

    def design(self) -> Design:
        return Design(self.stages, len(self.rows()), self.alpha, self.spending)


@dataclass(frozen=True)
class Row:
    """One comparison of the question: a claim, a pair and the metric's margin (None: none)."""

    claim: ClosedLoopClaim
    pair: Pair
    margin: float | None

    @property
    def metric(self) -> str:
        return self.claim.metric

    @property
    def comparison(self) -> str:
        return f"{self.pair.a.upper()}{self.claim.effect.joiner}{self.pair.b.upper()}"

    @property
    def name(self) -> str:
        return self.claim.name

    @property
    def models(self) -> tuple[str, str]:
        return (self.pair.a, self.pair.b)


@dataclass(frozen=True)
class Plan:
    """A stage's runs: trained draws per model, and seeds per draw (the first ``first_draws``
    draws of a model have ``first_seeds``, later ones ``later_seeds``)."""

    draws: Mapping[str, int]
    first_draws: int
    first_seeds: int
    later_seeds: int

    def seeds_of(self, replicate: int) -> int:
        return self.first_seeds if replicate < self.first_draws else self.later_seeds

    def as_config(self) -> dict[str, Any]:
        """The ``question.plan`` section the ``question`` target reads."""
        return {
            "draws": dict(self.draws),
            "first_draws": self.first_draws,
            "first_seeds": self.first_seeds,
            "later_seeds": self.later_seeds,
        }

    @classmethod
    def from_config(cls, plan: Mapping[str, Any]) -> Plan:
        return cls(
            {str(k): int(v) for k, v in plan["draws"].items()},
            int(plan["first_draws"]),
            int(plan["first_seeds"]),
            int(plan["later_seeds"]),
        )


def stage_runs(settings: QuestionSettings, plan: Plan) -> list[RunId]:
    """Every run a stage's rows read: each model's draws inside each NMPC on the ground-truth
    plant, at every η, on the draw's seeds (the study's folder names: ``RunId``)."""
    return [
        RunId(settings.study, TRUTH, model, controller, eta, seed, replicate)
        for model, draws in plan.draws.items()
        for replicate in range(draws)
        for controller in NMPCS
        for eta in settings.etas
        for seed in range(plan.seeds_of(replicate))
    ]


def run_overrides(config: Mapping[str, Any], settings: QuestionSettings, plan: Plan) -> dict:
    """The config a stage's Snakemake run merges over the user's: the ground-truth study runs
    every question model inside the NMPCs for up to the stage's draws; every other study keeps
    the draws it has (``all`` becomes the list it meant), so the grid grows by the question's
    runs alone; ``training.max_trainings`` is the last stage's in every stage (twice its draws,
    or a fixed cap grown in proportion); ``question.plan`` is the stage's."""
    replicates = int(config["training"]["replicates"])
    studies: dict[str, Any] = {}
    for name, grid in config["study"]["studies"].items():
        if name == settings.study:
            internal = list(grid.get("internal") or [])
            internal += [m for m in settings.models if m not in internal]
            controllers = list(grid["controllers"]) + [
                c for c in NMPCS if c not in grid["controllers"]
            ]
            studies[name] = {"internal": internal, "controllers": controllers, "replicates": "all"}
        elif grid.get("replicates", [0]) == "all":
            studies[name] = {"replicates": list(range(replicates))}
    most = max(replicates, *plan.draws.values())
    # one cap of trainings per model for every stage, the last stage's (2R by default, or the
    # fixed cap grown in proportion): a draw's cap never changes between stages, so no stage
    # redoes a draw another made (cape.models.draws.deciding_cap)
    cap = config["training"].get("max_trainings")
    last = max(most, settings.stages[-1])
    cap = 2 * last if cap is None else max(int(cap), math.ceil(int(cap) * last / replicates))
    training: dict[str, Any] = {"replicates": most, "max_trainings": cap}
    return {
        "training": training,
        "study": {"studies": studies},
        "question": {"plan": plan.as_config()},
    }


@dataclass
class RowState:
    """A row through the looks: each look's result, and its decision once settled."""

    row: Row
    looks: list[Look] = field(default_factory=list)

    @property
    def decision(self) -> str:
        return self.looks[-1].decision if self.looks else OPEN

    @property
    def settled(self) -> bool:
        return self.decision in SETTLED

    @property
    def done(self) -> bool:
        """Settled, or inconclusive for good (the cap, or a draw it lost)."""
        return self.decision != OPEN


def draw_values(runs: pd.DataFrame, row: Row, draws: int) -> list[float]:
    """The row's effect per training draw (the mean over its seeds, paired by seed), for the
    first ``draws`` draws of its models: a draw with no finite value is left out."""
    selected = row.claim.select(runs)
    per = per_seed(selected, row.claim) if len(selected) else {}
    effects = pair_effects(per, row.pair, row.claim)
    out = []
    for replicate in range(draws):
        values = [v for v in effects.get(replicate, []) if math.isfinite(v)]
        if values:
            out.append(float(np.mean(values)))
    return out


def evaluate(
    runs: pd.DataFrame, states: Sequence[RowState], design: Design, stage: int
) -> list[RowState]:
    """Look ``stage`` at every row still open: its decision from its draws' effects at the
    stage's draws. A row with fewer values than that (a draw untrained at the cap, or with no
    finite effect) cannot be looked at as planned: it is inconclusive for good, said in its
    ``why``, and buys no more draws. Decided rows keep their decision."""
    n = design.looks[stage]
    last = stage == len(design.looks) - 1
    nothing = (math.nan,) * 6
    for state in states:
        if state.done:
            continue
        values = draw_values(runs, state.row, n)
        if len(values) < n:
            why = f"{len(values)} of {n} draws have a value (a draw untrained, or no finite effect)"
            state.looks.append(Look(len(values), *nothing, INCONCLUSIVE, why))
            continue
        side = float(np.sign(state.row.pair.paper_effect))
        state.looks.append(look(values, design, state.row.margin, side, last))
    return list(states)


def next_draws(states: Iterable[RowState], current: Mapping[str, int], n: int) -> dict[str, int]:
    """Draws per model at the next look: ``n`` for every model of a row still open, the
    current number for the others (draws are added only where a row needs them)."""
    open_models = {m for s in states if not s.done for m in s.row.models}
    return {m: (max(n, d) if m in open_models else d) for m, d in current.items()}


def later_seeds(
    runs: pd.DataFrame,
    states: Sequence[RowState],
    draws: int,
    seeds: int,
    cost_ratio: float,
    least: int,
) -> tuple[int, pd.DataFrame]:
    """The seeds per later draw: each open row's two-stage optimum from its variance
    components over the first look's ``draws`` × ``seeds`` (``sequential.seeds_per_draw``; the
    cost of a draw over the cost of one seed's runs, ``cost_ratio``), then the median over the
    rows, rounded up. Returns it and the components per row (the report's)."""
    records = []
    for state in states:
        if state.done:
            continue
        row = state.row
        selected = row.claim.select(runs)
        effects = pair_effects(per_seed(selected, row.claim), row.pair, row.claim)
        table = [effects.get(r, [])[:seeds] for r in range(draws)]
        if any(len(t) < seeds for t in table) or seeds < 2:
            continue
        between, within = components(np.asarray(table, dtype=float)[None])
        n = seeds_per_draw(between, within, cost_ratio, least, seeds)
        records.append(
            {
                "claim": row.name,
                "comparison": row.comparison,
                "between_var": float(between[0]),
                "within_var": float(within[0]),
                "seeds": int(n[0]),
            }
        )
    frame = pd.DataFrame(
        records, columns=["claim", "comparison", "between_var", "within_var", "seeds"]
    )
    if frame.empty:
        return seeds, frame
    return math.ceil(float(frame["seeds"].median())), frame
