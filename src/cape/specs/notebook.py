"""What a notebook reads: the config sections its job file holds, typed."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from cape.config import schema_default, setting
from cape.specs import JSON, Entry, entries
from cape.specs.run import DisturbancesSpec, ReferenceSpec
from cape.specs.study import StudySpec
from cape.specs.training import HealthSettings


@dataclass(frozen=True)
class ScorecardSettings:
    """``scorecard`` (table 8's verdicts): the power ``draws needed`` plans for, the most draws
    it names, and each metric's margin of no practical difference (SPEC §10, revision 6); a
    setting not given is the schema's."""

    power: float = field(default_factory=lambda: float(schema_default("scorecard.power")))
    most_draws: int = field(default_factory=lambda: int(schema_default("scorecard.most_draws")))
    margins: Mapping[str, float] = field(default_factory=dict)
    """Metric → the margin of no practical difference (``scorecard.margins``): a row of that
    metric whose effect the two one-sided tests put inside ±margin is ``equivalent``."""

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> ScorecardSettings:
        return cls.of(setting(config, "scorecard", ""))

    @classmethod
    def of(cls, scorecard: Mapping[str, JSON] | None) -> ScorecardSettings:
        """From the ``scorecard`` section itself (as a scorecard's evidence records it)."""
        scorecard = scorecard or {}
        margins = setting(scorecard, "margins", "scorecard")
        return cls(
            float(setting(scorecard, "power", "scorecard")),
            int(setting(scorecard, "most_draws", "scorecard")),
            MappingProxyType({str(k): float(v) for k, v in margins.items()}),
        )


@dataclass(frozen=True)
class NotebookSpec:
    """The models' and controllers' entries, the disturbances, the study, the reference, the
    training checks and the scorecard's settings; a section the notebook does not read
    (``cape.study.reports.outputs``: its ``reads``) is empty, or None."""

    models: Mapping[str, Entry]
    controllers: Mapping[str, Entry]
    disturbances: DisturbancesSpec | None
    study: StudySpec | None
    reference: ReferenceSpec | None
    health: HealthSettings | None
    scorecard: ScorecardSettings | None

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> NotebookSpec:
        has_reference = all(k in config for k in ("reference", "tracks", "data"))
        training = config.get("training") or {}
        return cls(
            models=entries(config.get("models") or {}),
            controllers=entries(config.get("controllers") or {}),
            disturbances=DisturbancesSpec.from_config(config) if "disturbances" in config else None,
            study=StudySpec.from_config(config, partial=True) if "study" in config else None,
            reference=ReferenceSpec.from_config(config) if has_reference else None,
            health=HealthSettings.from_config(config) if "health" in training else None,
            scorecard=ScorecardSettings.from_config(config) if "scorecard" in config else None,
        )

    def controller_labels(self) -> dict[str, str]:
        """Each controller's label (its name where it has none)."""
        return {name: str(entry.get("label", name)) for name, entry in self.controllers.items()}
