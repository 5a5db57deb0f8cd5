"""What a notebook reads: the config sections its job specification holds, typed."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from cape.specs.run import ReferenceSpec
from cape.specs.study import StudySpec


@dataclass(frozen=True)
class NotebookSpec:
    """The models' and controllers' entries, the disturbances, the study, the reference, the
    training checks and the scorecard's settings; a section the notebook does not read
    (``cape.study.outputs``: its ``reads``) is empty, or None."""

    models: Mapping[str, Mapping[str, Any]]
    controllers: Mapping[str, Mapping[str, Any]]
    disturbances: Mapping[str, Any]
    study: StudySpec | None
    reference: ReferenceSpec | None
    health: Mapping[str, Any]
    scorecard: Mapping[str, Any] | None

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> NotebookSpec:
        has_reference = all(k in config for k in ("reference", "tracks", "data"))
        return cls(
            models=MappingProxyType(dict(config.get("models") or {})),
            controllers=MappingProxyType(dict(config.get("controllers") or {})),
            disturbances=MappingProxyType(dict(config.get("disturbances") or {})),
            study=StudySpec.from_config(config, partial=True) if "study" in config else None,
            reference=ReferenceSpec.from_config(config) if has_reference else None,
            health=MappingProxyType(dict((config.get("training") or {}).get("health") or {})),
            scorecard=config.get("scorecard"),
        )

    def controller_labels(self) -> dict[str, str]:
        """Each controller's label (its name where it has none)."""
        return {name: str(entry.get("label", name)) for name, entry in self.controllers.items()}
