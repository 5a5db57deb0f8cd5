"""Which configured models a plant or internal-model name reads (light: no NumPy, no CasADi).

A run names its plant and its controller's internal model: ``truth``, a model name (its learned
Φ) or ``<model>-fixed`` (its frozen Φ). The ground-truth internal model borrows a configured
model's physics structure (Deep Dynamics' where the grid has it). The workflow passes a run only
the model entries it reads, so adding a model to the grid never reruns another model's runs.
"""

from __future__ import annotations

from typing import Any


def truth_structure(models: dict[str, Any]) -> str:
    """The model whose physics structure the ground-truth internal model takes (SPEC §5.1)."""
    if not models:
        raise ValueError("the configuration names no models")
    return "ddm" if "ddm" in models else next(iter(models))


def models_read(models: dict[str, Any], *names: str) -> dict[str, Any]:
    """The entries of ``models`` that plants or internal models ``names`` read, in config order."""
    wanted = {name.partition("-")[0] for name in names if name != "truth"}
    if "truth" in names:
        wanted.add(truth_structure(models))
    return {name: entry for name, entry in models.items() if name in wanted}
