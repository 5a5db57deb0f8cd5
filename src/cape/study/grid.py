"""The study grid (SPEC §8): every run of a config, enumerated once, by ``study_grid``.

Each draw (replicate) r runs disturbance seeds of its own, ``StudySpec.draw_seeds``: r·stride +
0 … S − 1, the same for every study, model and controller of the draw, disjoint from every other
draw's (SPEC §8, §10 revision 7); draw 0's are 0 … S − 1.

A run's result depends on its plant, internal model, controller, η, seed and (when it uses a
trained model) replicate, never on the study that asks for it. So when two studies ask for the
same run (the ablation's diagonal, internal = plant, repeats runs of the learned study), it is
computed once, in the folder of the first study of the config that has it (``canonical``), and
both studies read it. The workflow's rules and ``cape aggregate`` both call ``study_grid``.
"""

from __future__ import annotations

from collections.abc import Callable

from cape.errors import CapeError
from cape.layout.runs import RunId
from cape.specs.study import StudySpec


def study_runs(spec: StudySpec, uses_internal: Callable[[str], bool]) -> list[RunId]:
    """Every run of every study of ``spec``, in the config's order. A controller with an
    internal model crosses the study's ``internal`` list (default: the plant's own model); one
    without (PID, RISE) runs once per plant, named after the plant. Each draw runs on its own
    seeds (``StudySpec.draw_seeds``)."""
    runs = []
    for study, grid in spec.studies.items():
        for replicate in grid.draws(spec.replicates):
            seeds = spec.draw_seeds(replicate)
            for plant in grid.plants:
                for controller in grid.controllers:
                    own = (plant,)
                    internals = (grid.internal or own) if uses_internal(controller) else own
                    for internal in internals:
                        for eta in spec.etas_of(grid):
                            for seed in seeds:
                                runs.append(
                                    RunId(study, plant, internal, controller, eta, seed, replicate)
                                )
    return runs


def count_runs(spec: StudySpec, uses_internal: Callable[[str], bool]) -> int:
    """How many runs ``study_runs`` would list, counted without listing them (a grid of a
    million seeds is refused by its count, before anything is built): every draw has
    ``study.seeds`` seeds, its own."""
    total = 0
    for grid in spec.studies.values():
        per_plant = sum(
            len(grid.internal or [None]) if uses_internal(c) else 1 for c in grid.controllers
        )
        reps = len(grid.draws(spec.replicates))
        total += reps * len(grid.plants) * per_plant * len(spec.etas_of(grid)) * spec.seeds
    return total


def check_grid_size(
    spec: StudySpec, uses_internal: Callable[[str], bool], source: str = "config"
) -> int:
    """The grid's run count, or ``CapeError`` when it exceeds ``study.max_runs``."""
    count = count_runs(spec, uses_internal)
    if count > spec.max_runs:
        raise CapeError(
            f"{source}: the grid of `study` expands to {count:,} runs, more than "
            f"`study.max_runs` ({spec.max_runs:,}); check `study.seeds` ({spec.seeds}) and "
            "the studies' lists, or raise `study.max_runs` if you mean it"
        )
    return count


def canonical(runs: list[RunId]) -> dict[RunId, RunId]:
    """Each run → the run that computes it: the first of ``runs`` with the same plant,
    internal model, controller, η and seed (and draw, where a trained model enters it). Draws
    do not share seeds, so a run without a trained model (the ground-truth plant under its true
    model) is shared between studies of one draw, never between draws."""
    first: dict[tuple[str, str, str, str, int, int], RunId] = {}
    return {run: first.setdefault(run.same_run(), run) for run in runs}


def study_grid(spec: StudySpec, source: str = "config") -> dict[RunId, RunId]:
    """Every run of ``spec``'s grid → the run that computes it (``canonical``), in the
    config's order; ``CapeError`` first when the grid exceeds ``study.max_runs``."""
    from cape.controllers import controller_class

    def uses_internal(name: str) -> bool:
        if name not in spec.controllers:
            raise CapeError(f"{source}: the grid names controller {name!r}, not in `controllers`")
        return bool(controller_class(name, spec.controllers[name]).needs_internal_model)

    check_grid_size(spec, uses_internal, source)
    return canonical(study_runs(spec, uses_internal))
