"""The ground-truth question's plan (SPEC §10, revision 6): its settings, rows, and which runs a
stage needs. Light on purpose: the workflow imports it whenever Snakemake reads the Snakefile
(the ``question`` target), so it imports neither pandas nor SciPy; what a look decides is
``cape.study.question.looks``'s.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from cape.config import schema_default
from cape.errors import CapeError
from cape.layout.names import NMPCS, TRUTH
from cape.layout.runs import RunId
from cape.specs.question import QuestionSpec, check_rule
from cape.specs.study import StudySpec, draw_seeds
from cape.training.draws import default_max_trainings

if TYPE_CHECKING:
    from cape.study.claims.declared import ClosedLoopClaim, Pair
    from cape.study.stats.sequential import Design


@dataclass(frozen=True)
class QuestionSettings:
    """What the question reads from the config: the models (best claimed first), the looks'
    draws per model, the family's α and the spending exponent, the margins by metric, the
    ground-truth study's name, η grid and seeds, the least seeds a later draw gets, the
    stride of the draws' seeds (``study.seed_stride``), the futility level and the most seeds
    a later draw gets (None: from the measured costs)."""

    models: tuple[str, ...]
    stages: tuple[int, ...]
    alpha: float
    spending: float
    margins: Mapping[str, float]
    study: str
    etas: tuple[str, ...]
    seeds: int
    least_seeds: int
    seed_stride: int = field(default_factory=lambda: int(schema_default("study.seed_stride")))
    """Draw r's seeds start at r·seed_stride (``draw_seeds``); unnamed: the schema's default."""
    futility: float = field(default_factory=lambda: float(schema_default("question.futility")))
    """A row whose chance of settling by the cap falls below this stops buying draws."""
    most_seeds: int | None = None
    """The most seeds a later draw gets; None: as many as cost what a draw costs (measured)."""

    @classmethod
    def from_config(cls, config: Mapping[str, Any], source: str = "config") -> QuestionSettings:
        """The settings (``cape.specs.question.QuestionSpec``), each cross-field problem one
        ``CapeError`` naming the key and fix."""
        q = QuestionSpec.from_config(config, source)
        return cls(q.models, q.stages, q.alpha, q.spending, dict(q.margins), q.study, q.etas,
                   q.seeds, q.least_seeds, q.seed_stride, q.futility, q.most_seeds)  # fmt: skip

    @classmethod
    def from_identity(cls, design: Mapping[str, Any]) -> QuestionSettings:
        """The settings a recorded design (``identity``) was made from; ``ValueError`` naming
        the field where it is not one: a key missing, a value of the wrong type, or one outside
        the config schema's bounds (``check_identity``: no look at 10¹² draws, whose
        boundaries would never be computed, no margin of −100 %)."""
        try:
            rule = design["seed rule"]
            settings = cls(
                tuple(str(m) for m in design["models"]),
                tuple(int(n) for n in design["stages"]),
                float(design["alpha"]),
                float(design["spending"]),
                {str(k): float(v) for k, v in design["margins"].items()},
                str(design["study"]),
                tuple(str(e) for e in design["etas"]),
                int(design["seeds"]),
                int(rule["least"]),
                int(rule["stride"]),
                float(design["futility"]),
                None if rule["most"] is None else int(rule["most"]),
            )
        except KeyError as exc:
            raise ValueError(f"field `{exc.args[0]}` is missing") from None
        except (TypeError, ValueError, OverflowError, AttributeError) as exc:
            raise ValueError(f"a field is not of its type ({exc})") from None
        settings.check_identity()
        return settings

    def check_identity(self) -> None:
        """``ValueError`` where these settings lie outside what the config's schema and
        ``from_config`` allow (a recorded design is read without the schema)."""
        from cape.config import validate_config

        fragment = {
            "question": {
                "models": list(self.models),
                "stages": list(self.stages),
                "alpha": self.alpha,
                "spending": self.spending,
                "futility": self.futility,
                "seeds": {"least": self.least_seeds, "most": self.most_seeds},
            },
            "scorecard": {"margins": dict(self.margins)},
            "study": {"seeds": self.seeds, "seed_stride": self.seed_stride},
        }
        try:
            validate_config(fragment, "the design", partial=True)
            check_rule(self.stages, self.least_seeds, self.most_seeds, self.seed_stride, "design")
        except CapeError as exc:
            raise ValueError(str(exc).split(". Fix the value")[0]) from None

    def draw_seeds(self, replicate: int, count: int) -> range:
        """Draw ``replicate``'s first ``count`` disturbance seeds, r·seed_stride + 0 … count − 1:
        the grid's (``StudySpec.draw_seeds``), shared by the models of the draw, disjoint from
        every other draw's. ``ValueError`` when ``count`` exceeds the stride."""
        return draw_seeds(replicate, count, self.seed_stride)

    def claims(self) -> tuple[ClosedLoopClaim, ...]:
        from cape.study.claims.declared import question_claims

        return question_claims(self.models)

    def rows(self) -> list[Row]:
        """Every (claim, pair), with its metric's margin; a relative margin m % becomes
        100·ln(1 + m/100) on the log-ratio scale (a/b within [1/(1 + m), 1 + m])."""
        from cape.study.claims.declared import LOG_RATIO

        rows = []
        for claim in self.claims():
            margin = self.margins.get(claim.metric)
            if margin is not None and claim.effect is LOG_RATIO:
                margin = 100 * math.log1p(margin / 100)
            rows += [Row(claim, pair, margin) for pair in claim.pairs]
        return rows

    def design(self) -> Design:
        from cape.study.stats.sequential import Design

        return Design(self.stages, len(self.rows()), self.alpha, self.spending, self.futility)

    def identity(self, recipes: Mapping[str, Any]) -> dict[str, Any]:
        """The question's design, fixed before its first look (SPEC §10, revision 7): what a
        rerun must share to continue it. ``recipes``: each model's config entry."""
        return {
            "models": list(self.models),
            "recipes": {m: recipes.get(m) for m in self.models},
            "stages": list(self.stages),
            "alpha": self.alpha,
            "spending": self.spending,
            "futility": self.futility,
            "margins": dict(sorted(self.margins.items())),
            "study": self.study,
            "etas": list(self.etas),
            "seeds": self.seeds,
            "seed rule": {
                "rule": "payoff",
                "least": self.least_seeds,
                "most": self.most_seeds,
                "stride": self.seed_stride,
            },
        }


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
    """A stage's runs: trained draws per model, and the seeds of each draw index (draw r of
    every model runs ``seeds[r]`` seeds, its own: ``QuestionSettings.draw_seeds``)."""

    draws: Mapping[str, int]
    seeds: tuple[int, ...]
    reused: frozenset[tuple[str, int]] = frozenset()
    """(model, draw) whose values come from a published question (``cape question --reuse``):
    their runs are not run again."""

    def __post_init__(self) -> None:
        most = max(self.draws.values(), default=0)
        if len(self.seeds) < most or any(n < 1 for n in self.seeds):
            raise ValueError(f"seeds for {most} draws needed, each at least one: {self.seeds}")

    def seeds_of(self, replicate: int) -> int:
        return self.seeds[replicate]

    def as_config(self) -> dict[str, Any]:
        """The ``question.plan`` section the ``question`` target reads."""
        plan: dict[str, Any] = {"draws": dict(self.draws), "seeds": list(self.seeds)}
        if self.reused:
            plan["reused"] = [[m, r] for m, r in sorted(self.reused)]
        return plan

    @classmethod
    def from_config(cls, plan: Mapping[str, Any], source: str = "question.plan") -> Plan:
        """From a validated ``question.plan``; ``CapeError`` naming the field where its seeds
        do not cover its draws."""
        draws = {str(k): int(v) for k, v in plan["draws"].items()}
        reused = frozenset((str(m), int(r)) for m, r in plan.get("reused") or ())
        try:
            return cls(draws, tuple(int(n) for n in plan["seeds"]), reused)
        except ValueError as exc:
            raise CapeError(
                f"{source}: field `question.plan.seeds` must give every draw up to "
                f"{max(draws.values(), default=0)} its seeds ({exc}); `cape question` writes "
                "this plan: run it again rather than editing results/question/stage.yaml"
            ) from exc


def stage_runs(settings: QuestionSettings, plan: Plan) -> list[RunId]:
    """Every run a stage's rows read: each model's draws inside each NMPC on the ground-truth
    plant, at every η, on the draw's own seeds (``QuestionSettings.draw_seeds``; the study's
    folder names: ``RunId``); none of a draw the plan reuses from a published question."""
    return [
        RunId(settings.study, TRUTH, model, controller, eta, seed, replicate)
        for model, draws in plan.draws.items()
        for replicate in range(draws)
        if (model, replicate) not in plan.reused
        for controller in NMPCS
        for eta in settings.etas
        for seed in settings.draw_seeds(replicate, plan.seeds_of(replicate))
    ]


def run_overrides(study: StudySpec, settings: QuestionSettings, plan: Plan) -> dict:
    """The config a stage's Snakemake run merges over the user's: the ground-truth study runs
    every question model inside the NMPCs for up to the stage's draws; every other study keeps
    the draws it has (``all`` becomes the list it meant), so the grid grows by the question's
    runs alone; ``training.max_trainings`` is the last stage's in every stage (twice its draws,
    or a fixed cap grown in proportion); ``question.plan`` is the stage's."""
    replicates = study.replicates
    studies: dict[str, Any] = {}
    for name, grid in study.studies.items():
        if name == settings.study:
            internal = list(grid.internal)
            internal += [m for m in settings.models if m not in internal]
            controllers = list(grid.controllers) + [c for c in NMPCS if c not in grid.controllers]
            studies[name] = {"internal": internal, "controllers": controllers, "replicates": "all"}
        elif grid.replicates == "all":
            studies[name] = {"replicates": list(range(replicates))}
    most = max(replicates, *plan.draws.values())
    # one cap of trainings per model for every stage, the last stage's (2R by default, or the
    # fixed cap grown in proportion): a draw's cap never changes between stages, so no stage
    # redoes a draw another made (cape.training.draws.deciding_cap)
    cap = study.max_trainings
    last = max(most, settings.stages[-1])
    cap = (
        default_max_trainings(last) if cap is None else max(cap, math.ceil(cap * last / replicates))
    )
    training: dict[str, Any] = {"replicates": most, "max_trainings": cap}
    return {
        "training": training,
        "study": {"studies": studies},
        "question": {"plan": plan.as_config()},
    }
