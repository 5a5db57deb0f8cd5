"""The study grid (SPEC §8): every run of a config, enumerated once, by ``study_grid``.

A run's result depends on its plant, internal model, controller, η, seed and (when it uses a
trained model) replicate, never on the study that asks for it. So when two studies ask for the
same run (the ablation's diagonal, internal = plant, repeats runs of the learned study), it is
computed once, in the folder of the first study of the config that has it (``canonical``), and
both studies read it. The workflow's rules and ``cape aggregate`` both call ``study_grid``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from cape.errors import CapeError
from cape.layout.runs import RunId


def study_replicates(grid: Mapping[str, Any], replicates: int) -> list[int]:
    """The training replicates a study runs for: its ``replicates`` (``all``: 0 … R−1, a list:
    those), default replicate 0 only (SPEC §8: the paper's study sets ``all``)."""
    chosen = grid.get("replicates", [0])
    return list(range(replicates)) if chosen == "all" else [int(r) for r in chosen]


def study_runs(
    study_config: Mapping[str, Any],
    etas: list[str],
    uses_internal: Callable[[str], bool],
    replicates: int = 1,
) -> list[RunId]:
    """Every run of every study of the config's ``study`` section, in the config's order.
    A controller with an internal model crosses the study's ``internal`` list (default: the
    plant's own model); one without (PID, RISE) runs once per plant, named after the plant.
    ``replicates``: the config's ``training.replicates`` (what ``replicates: all`` means)."""
    runs = []
    seeds = range(int(study_config["seeds"]))
    for study, grid in study_config["studies"].items():
        for replicate in study_replicates(grid, replicates):
            for plant in grid["plants"]:
                for controller in grid["controllers"]:
                    own = [plant]
                    internals = (grid.get("internal") or own) if uses_internal(controller) else own
                    for internal in internals:
                        for eta in grid.get("eta", etas):
                            for seed in seeds:
                                runs.append(
                                    RunId(study, plant, internal, controller, eta, seed, replicate)
                                )
    return runs


def count_runs(
    study_config: Mapping[str, Any],
    etas: list[str],
    uses_internal: Callable[[str], bool],
    replicates: int = 1,
) -> int:
    """How many runs ``study_runs`` would list, counted without listing them (a grid of a
    million seeds is refused by its count, before anything is built)."""
    seeds = int(study_config["seeds"])
    total = 0
    for grid in study_config["studies"].values():
        per_plant = sum(
            len(grid.get("internal") or [None]) if uses_internal(c) else 1
            for c in grid["controllers"]
        )
        reps = len(study_replicates(grid, replicates))
        total += reps * len(grid["plants"]) * per_plant * len(grid.get("eta", etas)) * seeds
    return total


def check_grid_size(
    study_config: Mapping[str, Any],
    etas: list[str],
    uses_internal: Callable[[str], bool],
    source: str = "config",
    replicates: int = 1,
) -> int:
    """The grid's run count, or ``CapeError`` when it exceeds ``study.max_runs``."""
    count = count_runs(study_config, etas, uses_internal, replicates)
    limit = int(study_config.get("max_runs", 20000))
    if count > limit:
        raise CapeError(
            f"{source}: the grid of `study` expands to {count:,} runs, more than "
            f"`study.max_runs` ({limit:,}); check `study.seeds` ({study_config['seeds']}) and "
            "the studies' lists, or raise `study.max_runs` if you mean it"
        )
    return count


def canonical(runs: list[RunId]) -> dict[RunId, RunId]:
    """Each run → the run that computes it: the first of ``runs`` with the same plant,
    internal model, controller, η and seed."""
    first: dict[tuple[str, str, str, str, int, int], RunId] = {}
    return {run: first.setdefault(run.same_run(), run) for run in runs}


def study_grid(config: Mapping[str, Any], source: str = "config") -> dict[RunId, RunId]:
    """Every run of ``config``'s grid → the run that computes it (``canonical``), in the
    config's order; ``CapeError`` first when the grid exceeds ``study.max_runs``. Reads the
    ``study`` section, ``disturbances.eta``, ``training.replicates`` and which of the
    ``controllers`` predict with an internal model."""
    from cape.config import section
    from cape.controllers import controller_class

    controllers = section(config, "controllers")

    def uses_internal(name: str) -> bool:
        if name not in controllers:
            raise CapeError(f"{source}: the grid names controller {name!r}, not in `controllers`")
        return bool(controller_class(name, controllers[name]).needs_internal_model)

    etas = list(section(config, "disturbances").get("eta", []))
    replicates = int(section(config, "training").get("replicates", 1))
    grid = section(config, "study")
    check_grid_size(grid, etas, uses_internal, source, replicates)
    return canonical(study_runs(grid, etas, uses_internal, replicates))
