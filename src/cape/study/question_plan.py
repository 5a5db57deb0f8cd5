"""The ground-truth question's plan (SPEC §10, revision 6): its settings, rows, and which runs a
stage needs. Light on purpose: the workflow imports it whenever Snakemake reads the Snakefile
(the ``question`` target), so it imports neither pandas nor SciPy; what a look decides is
``cape.study.question``'s.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from cape.config import schema_default
from cape.errors import CapeError
from cape.layout.names import NMPCS, TRUTH
from cape.layout.runs import RunId
from cape.specs.study import StudySpec, draw_seeds

if TYPE_CHECKING:
    from cape.study.claims import ClosedLoopClaim, Pair
    from cape.study.sequential import Design


@dataclass(frozen=True)
class QuestionSettings:
    """What the question reads from the config: the models (best claimed first), the looks'
    draws per model, the family's α and the spending exponent, the margins by metric, the
    ground-truth study's name, η grid and seeds, the least seeds a later draw gets, and the
    stride of the draws' seeds (``study.seed_stride``)."""

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
        stride = config["study"].get("seed_stride")  # None: sections without their defaults
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
            int(schema_default("study.seed_stride") if stride is None else stride),
        )

    def draw_seeds(self, replicate: int, count: int) -> range:
        """Draw ``replicate``'s first ``count`` disturbance seeds, r·seed_stride + 0 … count − 1:
        the grid's (``StudySpec.draw_seeds``), shared by the models of the draw, disjoint from
        every other draw's. ``ValueError`` when ``count`` exceeds the stride."""
        return draw_seeds(replicate, count, self.seed_stride)

    def claims(self) -> tuple[ClosedLoopClaim, ...]:
        from cape.study.claims import question_claims

        return question_claims(self.models)

    def rows(self) -> list[Row]:
        """Every (claim, pair), with its metric's margin; a relative margin m % becomes
        100·ln(1 + m/100) on the log-ratio scale (a/b within [1/(1 + m), 1 + m])."""
        from cape.study.claims import LOG_RATIO

        rows = []
        for claim in self.claims():
            margin = self.margins.get(claim.metric)
            if margin is not None and claim.effect is LOG_RATIO:
                margin = 100 * math.log1p(margin / 100)
            rows += [Row(claim, pair, margin) for pair in claim.pairs]
        return rows

    def design(self) -> Design:
        from cape.study.sequential import Design

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
    plant, at every η, on the draw's own seeds (``QuestionSettings.draw_seeds``; the study's
    folder names: ``RunId``)."""
    return [
        RunId(settings.study, TRUTH, model, controller, eta, seed, replicate)
        for model, draws in plan.draws.items()
        for replicate in range(draws)
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
    # redoes a draw another made (cape.models.draws.deciding_cap)
    cap = study.max_trainings
    last = max(most, settings.stages[-1])
    cap = 2 * last if cap is None else max(cap, math.ceil(cap * last / replicates))
    training: dict[str, Any] = {"replicates": most, "max_trainings": cap}
    return {
        "training": training,
        "study": {"studies": studies},
        "question": {"plan": plan.as_config()},
    }
