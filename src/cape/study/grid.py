"""A run's identity and the study grid (SPEC §8): the one place a run's folder is spelled.

A run is (study, training replicate, plant, internal model, controller, η, seed); its files live
in ``<root>/<study>/rep<r>/<plant>/<internal>/<controller>/eta<η>/seed<s>/``. The replicate is
the training draw of the learned models the run uses (SPEC §4: replicate r is trained with
training seed ``training.seed + r``). The workflow's targets, the
aggregation and the notebooks all go through ``RunId``, and the grid of a config is enumerated
once, by ``study_runs``.

A run's result depends on its plant, internal model, controller, η, seed and (when it uses a
trained model) replicate, never on the study that asks for it. So when two studies ask for the
same run (the ablation's diagonal, internal = plant, repeats runs of the learned study), it is
computed once, in the folder of the first study of the config that has it (``canonical``), and
both studies read it.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cape.errors import CapeError

RUNS_ROOT = "results/runs"
RUN_FILES = ("metrics.json", "timing.json", "timeseries.parquet")
"""A run folder's files: written together by ``cape rollout``, the only files it replaces."""

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


@dataclass(frozen=True)
class RunId:
    """One closed-loop run of a study. ``eta`` is the grid's label (it names a folder);
    ``replicate`` the training draw of the learned models it uses (SPEC §4)."""

    study: str
    plant: str
    internal: str
    controller: str
    eta: str
    seed: int
    replicate: int = 0

    def parts(self) -> tuple[str, ...]:
        """The run's folder names, root to leaf: the one place the layout is spelled."""
        return (self.study, f"rep{self.replicate}", self.plant, self.internal, self.controller,
                f"eta{self.eta}", f"seed{self.seed}")  # fmt: skip

    def folder(self, root: str | Path = RUNS_ROOT) -> Path:
        """The run's folder under ``root``."""
        return Path(root, *self.parts())

    def stem(self) -> str:
        """The run as one file name (its figure's): the folder names joined by ``_``."""
        return "_".join(self.parts())

    @classmethod
    def glob(cls) -> str:
        """A glob of every run folder under a root: ``*`` for each field."""
        return re.sub(r"\{\w+\}", "*", str(cls.wildcards().folder(".")))

    @classmethod
    def wildcards(cls) -> RunId:
        """The run of a workflow rule: every field a Snakemake wildcard of the same name."""
        return cls(
            "{study}", "{plant}", "{internal}", "{controller}", "{eta}", "{seed}", "{replicate}"
        )  # type: ignore[arg-type]

    @classmethod
    def parse(cls, path: str | Path) -> RunId:
        """The run whose folder (or a file in it) is ``path``: ``parts`` read backwards."""
        path = Path(path)
        templates = cls.wildcards().parts()
        if not path.name.startswith(templates[-1].split("{")[0]):  # a file in the folder
            path = path.parent
        names = path.parts[-len(templates) :]
        fields: dict[str, str] = {}
        for template, name in zip(templates, names, strict=False):
            prefix, field = template[: template.index("{")], template[template.index("{") + 1 : -1]
            if not name.startswith(prefix):
                break
            fields[field] = name[len(prefix) :]
        numbers = ("seed", "replicate")
        if len(fields) != len(templates) or not all(fields[k].isdigit() for k in numbers):
            layout = "/".join(templates).replace("{", "<").replace("}", ">")
            raise ValueError(f"{path}: not a run folder (…/{layout})")
        return cls(**{**fields, **{k: int(fields[k]) for k in numbers}})  # type: ignore[arg-type]

    def uses_trained_model(self) -> bool:
        """True unless plant and internal model are both the ground truth (then no replicate's
        network or frozen Φ enters the run)."""
        return not (self.plant == "truth" and self.internal == "truth")

    def same_run(self) -> tuple[str, str, str, str, int, int]:
        """What the run's result depends on: everything but the study, and the replicate only
        where a trained model enters the run."""
        replicate = self.replicate if self.uses_trained_model() else 0
        return (self.plant, self.internal, self.controller, self.eta, self.seed, replicate)


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
