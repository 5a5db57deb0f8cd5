"""What the study's grid and its summaries read: the studies, the seeds, η, the draws (SPEC §8)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from cape.config import section, setting
from cape.specs import Entry, entries


def draw_seeds(replicate: int, count: int, stride: int) -> range:
    """Draw ``replicate``'s first ``count`` disturbance seeds: r·stride + 0 … count − 1 (SPEC
    §10, revision 7), disjoint from every other draw's when ``count`` ≤ ``stride``;
    ``ValueError`` when it is not, or for a negative draw or count."""
    if replicate < 0 or count < 0:
        raise ValueError(f"draw {replicate}, {count} seeds: neither can be negative")
    if count > stride:
        raise ValueError(
            f"{count} seeds per draw exceed `study.seed_stride` ({stride}): draw {replicate}'s "
            f"seeds would overlap draw {replicate + 1}'s"
        )
    return range(replicate * stride, replicate * stride + count)


@dataclass(frozen=True)
class StudyGrid:
    """One study of ``study.studies``: its plants × controllers (× internal models for a
    controller with one) × η × seeds, for its draws."""

    kind: str
    plants: tuple[str, ...]
    controllers: tuple[str, ...]
    internal: tuple[str, ...]
    """The NMPCs' internal models; empty: each plant's own model."""
    eta: tuple[str, ...] | None
    """Its η; None: ``disturbances.eta``."""
    replicates: str | tuple[int, ...]
    """``all`` (every draw) or the draws it runs for (default: draw 0)."""

    @classmethod
    def from_config(cls, entry: Mapping[str, Any]) -> StudyGrid:
        """From one entry of ``study.studies``."""
        chosen = setting(entry, "replicates", "study.studies.*")
        eta = entry.get("eta")
        return cls(
            kind=str(setting(entry, "kind", "study.studies.*")),
            plants=tuple(entry["plants"]),
            controllers=tuple(entry["controllers"]),
            internal=tuple(entry.get("internal") or ()),
            eta=None if eta is None else tuple(eta),
            replicates="all" if chosen == "all" else tuple(int(r) for r in chosen),
        )

    def draws(self, replicates: int) -> list[int]:
        """The draws it runs for, given the config's ``training.replicates``."""
        return list(range(replicates)) if self.replicates == "all" else list(self.replicates)


@dataclass(frozen=True)
class StudySpec:
    """The ``study`` section with what gives it meaning: η, the number of draws, the
    controllers' entries (which of them predict with an internal model) and the models."""

    studies: Mapping[str, StudyGrid]
    seeds: int
    seed_stride: int
    """``study.seed_stride``: draw r's disturbance seeds start at r·seed_stride (``draw_seeds``)."""
    max_runs: int
    paper: str | None
    ground_truth: str | None
    reference_model: str | None
    primary_metric: str | None
    etas: tuple[str, ...]
    replicates: int
    max_trainings: int | None
    """``training.max_trainings``: None, the default cap (twice the draws)."""
    controllers: Mapping[str, Entry]
    models: Mapping[str, Entry]

    @classmethod
    def from_config(cls, config: Mapping[str, Any], partial: bool = False) -> StudySpec:
        """From a validated config, or the sections a job reads: ``study``, ``controllers``,
        ``disturbances`` and ``training``, each missing one a ``CapeError``; ``partial`` (a
        notebook's sections): without ``disturbances`` or ``training``, no η and the schema's
        training settings."""
        study = section(config, "study")
        controllers = section(config, "controllers")
        if partial:
            etas = (config.get("disturbances") or {}).get("eta", [])
            training = config.get("training") or {}
        else:
            etas = section(config, "disturbances").get("eta", [])
            training = section(config, "training")
        cap = setting(training, "max_trainings", "training")
        return cls(
            studies=MappingProxyType(
                {name: StudyGrid.from_config(grid) for name, grid in study["studies"].items()}
            ),
            seeds=int(study["seeds"]),
            seed_stride=int(setting(study, "seed_stride", "study")),
            max_runs=int(setting(study, "max_runs", "study")),
            paper=study.get("paper"),
            ground_truth=setting(study, "ground_truth", "study"),
            reference_model=setting(study, "reference_model", "study"),
            primary_metric=setting(study, "primary_metric", "study"),
            etas=tuple(etas),
            replicates=int(setting(training, "replicates", "training")),
            max_trainings=None if cap is None else int(cap),
            controllers=entries(controllers),
            models=entries(config.get("models") or {}),
        )

    def draw_seeds(self, replicate: int, count: int | None = None) -> range:
        """Draw ``replicate``'s disturbance seeds (SPEC §10, revision 7): r·seed_stride + 0 …
        count − 1 (``count``: the study's seeds by default), the same for every model, plant
        and controller of the draw, disjoint from every other draw's; draw 0's are 0 … S − 1.
        ``ValueError`` when ``count`` exceeds the stride (the seeds would reach draw r + 1's),
        or for a negative draw or count."""
        return draw_seeds(replicate, self.seeds if count is None else count, self.seed_stride)

    def internal_studies(self) -> tuple[str, ...]:
        """The studies whose runs are about their internal model (the ground-truth study's
        kind, not the ablation's, which varies both)."""
        return tuple(
            name for name, g in self.studies.items() if g.internal and g.kind != "ablation"
        )

    def etas_of(self, grid: StudyGrid) -> tuple[str, ...]:
        """A study's η: its own, else the config's."""
        return self.etas if grid.eta is None else grid.eta
