"""A run's identity: the one place a run's folder is spelled.

A run is (study, training replicate, plant, internal model, controller, η, seed); its files live
in ``<root>/<study>/rep<r>/<plant>/<internal>/<controller>/eta<η>/seed<s>/``. The replicate is
the training draw of the learned models the run uses (SPEC §4). The workflow's targets, the
aggregation, the rollout command and the notebooks all go through ``RunId``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from cape.layout import paths
from cape.layout.names import TRUTH, replicate_name

RUNS_ROOT = paths.RUNS
RUN_FILES = (paths.METRICS, paths.TIMING, paths.SERIES)
"""A run folder's files: written together by ``cape rollout``, the only files it replaces."""


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
        replicate = replicate_name(self.replicate)
        return (self.study, replicate, self.plant, self.internal, self.controller,
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
        return not (self.plant == TRUTH and self.internal == TRUTH)

    def same_run(self) -> tuple[str, str, str, str, int, int]:
        """What the run's result depends on: everything but the study, and the replicate only
        where a trained model enters the run (draws have seeds of their own, SPEC §10 revision
        7: runs of two draws never coincide, those of two studies of one draw may)."""
        replicate = self.replicate if self.uses_trained_model() else 0
        return (self.plant, self.internal, self.controller, self.eta, self.seed, replicate)
