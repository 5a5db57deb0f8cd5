"""The names CAPE gives things: folder-safe identifiers, plants, training replicates.

A plant (or an NMPC's internal model) is named ``truth`` (the ground-truth car, SPEC §1), a
model's name (its learned Φ) or ``<model>-fixed`` (its frozen Φ, SPEC §4.5): ``PlantName`` parses
and prints these names, and nothing else does. A training replicate (draw) r is spelled
``rep<r>`` in every folder and column that carries it (``replicate_name``); nothing reads it
back out of a name: whoever needs the number is given it.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

from cape.errors import CapeError

NAME_PATTERN = r"^[A-Za-z][A-Za-z0-9_]{0,39}$"
"""Names that become folder and file names (studies, models, controllers, tracks, sources):
identifiers of at most 40 characters. The config schema holds the same pattern (a test keeps
the two equal), so a name can never climb out of ``results/`` or confuse the layout."""


def check_name(name: str, where: str) -> str:
    """``name``, or ``CapeError`` when it is not an identifier (``NAME_PATTERN``)."""
    if not re.fullmatch(NAME_PATTERN, name):
        raise CapeError(
            f"{where} {name!r}: a name is a letter followed by up to 39 letters, digits or "
            "underscores (it names folders); rename it"
        )
    return name


TRUTH = "truth"
NMPCS = ("nmpc", "anmpc", "rnmpc")
"""The NMPC family's controllers, whose runs the claims and the question read."""
"""The ground-truth plant's (and internal model's) name."""
FIXED_SUFFIX = "-fixed"

PlantKind = Literal["truth", "learned", "fixed"]


@dataclass(frozen=True)
class PlantName:
    """A plant or internal-model name, parsed: ``kind`` and the configured ``model`` it reads
    (None for the ground truth). ``str(plant)`` is its name."""

    kind: PlantKind
    model: str | None = None

    def __str__(self) -> str:
        if self.kind == "truth":
            return TRUTH
        return f"{self.model}{FIXED_SUFFIX}" if self.kind == "fixed" else str(self.model)

    @property
    def is_truth(self) -> bool:
        return self.kind == "truth"

    @classmethod
    def parse(
        cls, name: str, models: Iterable[str] | None = None, where: str = "--plant"
    ) -> PlantName:
        """The plant ``name`` names; with ``models`` (the configured names), ``CapeError``
        unless it is ``truth``, one of them or ``<one of them>-fixed``."""
        if name == TRUTH:
            return cls("truth")
        model, fixed = (
            (name[: -len(FIXED_SUFFIX)], True) if name.endswith(FIXED_SUFFIX) else (name, False)
        )
        known = None if models is None else list(models)
        if not model or (known is not None and model not in known):
            choices = ", ".join(known or [])
            raise CapeError(
                f"{where} {name}: expected {TRUTH}, a model name ({choices}) or "
                f"<model>{FIXED_SUFFIX}"
            )
        return cls("fixed" if fixed else "learned", model)


def plant_names(models: Iterable[str]) -> list[str]:
    """Every plant (and internal-model) name of these models: the ground truth, each model,
    each model's frozen-Φ variant."""
    models = list(models)
    return [TRUTH, *models, *(f"{m}{FIXED_SUFFIX}" for m in models)]


REPLICATE_PREFIX = "rep"


def replicate_name(replicate: int | str) -> str:
    """Training replicate (draw) ``replicate`` as folders and columns spell it: ``rep<r>``
    (a wildcard ``{replicate}`` gives the pattern)."""
    return f"{REPLICATE_PREFIX}{replicate}"


def truth_structure(models: Mapping[str, Any]) -> str:
    """The model whose physics structure the ground-truth internal model takes (SPEC §5.1):
    Deep Dynamics' where the config has it, else the first model's."""
    if not models:
        raise ValueError("the configuration names no models")
    return "ddm" if "ddm" in models else next(iter(models))


def models_read(models: Mapping[str, Any], *names: str) -> dict[str, Any]:
    """The entries of ``models`` that plants or internal models ``names`` read, in config
    order (the workflow passes a run only these, so adding a model reruns no other's runs)."""
    wanted = {PlantName.parse(name).model for name in names if name != TRUTH}
    if TRUTH in names:
        wanted.add(truth_structure(models))
    return {name: entry for name, entry in models.items() if name in wanted}
