"""What the ground-truth question reads (SPEC §10, revision 6; docs/question.md): its models,
looks, error rate, margins and seed rule, the ground-truth study it runs in, and the plan of its
current stage (``question.plan``, which `cape question` writes)."""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from cape.config import section, setting
from cape.errors import CapeError
from cape.layout.names import NMPCS
from cape.specs.notebook import ScorecardSettings
from cape.specs.study import StudySpec


@dataclass(frozen=True)
class StagePlan:
    """``question.plan``: a stage's trained draws per model, the seeds of each draw index, and
    the (model, draw) pairs whose values a published question gives (``reused``)."""

    draws: Mapping[str, int]
    seeds: tuple[int, ...]
    reused: tuple[tuple[str, int], ...]

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> StagePlan | None:
        """The current stage's plan; None without one (no `cape question` stage is running)."""
        plan = (config.get("question") or {}).get("plan")
        if not plan:
            return None
        return cls(
            MappingProxyType({str(m): int(n) for m, n in plan["draws"].items()}),
            tuple(int(n) for n in plan["seeds"]),
            tuple((str(m), int(r)) for m, r in plan.get("reused") or ()),
        )


@dataclass(frozen=True)
class QuestionSpec:
    """The ``question`` section with what gives it meaning: the models (best claimed first), the
    looks' draws per model, the family's α and the spending exponent, the margins by metric
    (``scorecard.margins``), the ground-truth study's name, η grid and seeds, the least and most
    seeds a later draw gets (None: from the measured costs), the stride of the draws' seeds
    (``study.seed_stride``), the futility level, and the current stage's plan."""

    models: tuple[str, ...]
    stages: tuple[int, ...]
    alpha: float
    spending: float
    margins: Mapping[str, float]
    study: str
    etas: tuple[str, ...]
    seeds: int
    least_seeds: int
    seed_stride: int
    futility: float
    most_seeds: int | None
    plan: StagePlan | None

    @classmethod
    def from_config(cls, config: Mapping[str, Any], source: str = "config") -> QuestionSpec:
        """The question's settings, each cross-field problem one ``CapeError`` naming the key
        and the fix."""
        q = config.get("question") or {}
        grid_spec = StudySpec.from_config(config, partial=True)
        study = grid_spec.ground_truth
        if not study or study not in grid_spec.studies:
            raise CapeError(
                f"{source}: `study.ground_truth` names no study of `study.studies` "
                f"({study!r}); the question runs on the ground-truth study: set it to one"
            )
        models = tuple(q.get("models") or ())
        unknown = [m for m in models if m not in section(config, "models")]
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
        missing = [c for c in NMPCS if c not in grid_spec.controllers]
        if missing:
            raise CapeError(
                f"{source}: the question reads the NMPCs' runs, and `controllers` lacks "
                f"{', '.join(missing)}; add them back"
            )
        seeds_of = setting(q, "seeds", "question")
        least = int(setting(seeds_of, "least", "question.seeds"))
        most = seeds_of.get("most")
        stride = grid_spec.seed_stride
        check_rule(stages, least, None if most is None else int(most), stride, source)
        return cls(
            models=models,
            stages=stages,
            alpha=float(setting(q, "alpha", "question")),
            spending=float(setting(q, "spending", "question")),
            margins=ScorecardSettings.from_config(config).margins,
            study=study,
            etas=grid_spec.etas_of(grid_spec.studies[study]),
            seeds=grid_spec.seeds,
            least_seeds=least,
            seed_stride=stride,
            futility=float(setting(q, "futility", "question")),
            most_seeds=None if most is None else int(most),
            plan=StagePlan.from_config(config),
        )


def check_rule(
    stages: tuple[int, ...], least: int, most: int | None, stride: int, source: str
) -> None:
    """The cross-field rules of the looks and the seed rule (of a config, or of a recorded
    design); ``CapeError`` naming the field."""
    if not stages or any(b <= a for a, b in itertools.pairwise(stages)):
        raise CapeError(f"{source}: field `question.stages` must increase: {list(stages)}")
    for key, value in (("least", least), ("most", most)):
        if value is not None and value > stride:
            raise CapeError(
                f"{source}: field `question.seeds.{key}` is {value}, more than "
                f"`study.seed_stride` ({stride}): a draw's seeds would reach the next "
                "draw's; lower it or raise the stride"
            )
    if most is not None and most < least:
        raise CapeError(
            f"{source}: field `question.seeds.most` ({most}) is below `question.seeds.least` "
            f"({least}); set most to at least {least}"
        )
