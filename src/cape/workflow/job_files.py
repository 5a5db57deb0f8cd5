"""The job files: the config sections a rule's command depends on, written as a small JSON file
named by its digest (``paths.SPEC``) that the command reads with ``--spec`` and turns into its
typed specification (``cape/specs``, each one's ``from_config``).

A rule gets the file's path from ``JobFiles`` (``JOBS`` in the rules), the one way from a rule to
its job file: changing a setting changes the digest, so exactly the jobs that read it rerun;
the command line stays short, whatever the config holds. These writers, ``cape.config`` and
``cape/specs`` are the only code that indexes the config (tests/test_config_reads.py).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cape.config import PRESENTATION_KEYS
from cape.errors import CapeError
from cape.layout import paths
from cape.layout.names import models_read
from cape.storage.io import write_text
from cape.study.reports.outputs import STUDY_NOTEBOOKS, WHOLE_STUDY_NOTEBOOKS

RUN_ONLY_KEYS = ("plant_envelope", "failure_window")
"""Rollout settings that judge or bound a run, which no controller's NLP reads."""

GRID_KEYS = ("replicates", "max_trainings")
"""The training section's keys that size the grid, which no one job reads."""

Config = Mapping[str, Any]


def write_job_file(job: str, text: str) -> str:
    """Write ``job``'s file of content ``text`` once (atomically) if absent; its path.

    Snakemake asks for it while it plans (a rule's params), so a dry run writes it too;
    ``CapeError`` in one line when it cannot be written (the rules reach it through
    ``start.Refusing``, which makes that its one line on stderr, not Snakemake's frames)."""
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    path = Path(paths.SPEC.format(job=job, digest=digest))
    try:
        if not path.exists():
            write_text(path, text)
        elif not path.is_file() or path.read_text(errors="replace") != text:
            raise CapeError(
                f"{path}: holds something other than the job specification named by this "
                "digest, which the workflow did not write; move it away and run again"
            )
    except OSError as exc:
        raise CapeError(
            f"{path}: cannot write the job's specification ({exc.strerror or exc}); the workflow "
            f"writes each job's settings under {paths.SPECS}/: make that folder writable"
        ) from None
    return str(path)


@dataclass(frozen=True)
class JobFiles:
    """Each job's file from the validated config: every method writes one (``write_job_file``)
    and returns its path, for the rule's ``--spec`` (or papermill's ``-f``)."""

    config: Config

    def write_sections(self, job: str, *names: str) -> str:
        """Only the named config sections (the training section less the grid's keys)."""
        chosen = {name: self.config[name] for name in names}
        if "training" in chosen:
            training = chosen["training"]
            chosen["training"] = {k: v for k, v in training.items() if k not in GRID_KEYS}
        return write_job_file(job, json.dumps(chosen, sort_keys=True))

    def write_notebook(self, name: str) -> str:
        """Notebook ``name``'s sections: those it declares it reads
        (``cape.study.reports.outputs``)."""
        declared = {**STUDY_NOTEBOOKS, **WHOLE_STUDY_NOTEBOOKS}[name]
        return self.write_sections(f"notebook_{name}", *declared.reads)

    def write_training(self, model: str, seed: int) -> str:
        """What training reads: the model's own entry (less its label and colour), the
        training's seed, threads and kernels, the sampling time and the split; nothing else, so
        that unrelated config edits never retrain a model."""
        config = self.config
        entry = {k: v for k, v in config["models"][model].items() if k not in PRESENTATION_KEYS}
        settings = {k: config["training"][k] for k in ("threads", "fused_adam", "compile")}
        kernels = {k: v for k, v in config["training"].get("kernels", {}).items() if v is not None}
        if kernels:  # unset pins change nothing, so they are not part of a training's identity
            settings["kernels"] = kernels
        text = json.dumps(
            {
                "models": {model: entry},
                "training": {**settings, "seed": int(seed)},
                "data": {k: config["data"][k] for k in ("ts", "split")},
            },
            sort_keys=True,
        )
        return write_job_file("train", text)

    def write_health(self, job: str, model: str) -> str:
        """What a training's health check (and a draw, which checks each verdict again) reads:
        the split and the checks' settings, the bar's models narrowed to this one (naming a new
        model there reruns no other check)."""
        checks = dict(self.config["training"]["health"])
        checks["models"] = [m for m in checks.get("models", []) if m == model]
        text = json.dumps(
            {"data": {"split": self.config["data"]["split"]}, "training": {"health": checks}},
            sort_keys=True,
        )
        return write_job_file(job, text)

    def write_rollout(self, controller: str, plant: str, internal: str) -> str:
        """What a run reads: the track data, the reference, the disturbances, the run
        settings, this controller's gains and the entries of the models its plant and internal
        model read (none of their labels or colours)."""
        return write_job_file("rollout", self._run_text(controller, plant, internal))

    def write_solver(self, controller: str, internal: str) -> str:
        """What building a controller's NLP reads: a run's settings less what only judges a
        run (``RUN_ONLY_KEYS``), for the internal model alone."""
        return write_job_file("solver", self._run_text(controller, internal, solver=True))

    def _run_text(self, controller: str, *names: str, solver: bool = False) -> str:
        config = self.config
        keys = ("tracks", "data", "reference", "disturbances", "rollout")
        chosen = {k: config[k] for k in keys}
        if solver:
            rollout = config["rollout"]
            chosen["rollout"] = {k: v for k, v in rollout.items() if k not in RUN_ONLY_KEYS}
        chosen["models"] = {
            name: {k: v for k, v in entry.items() if k not in PRESENTATION_KEYS}
            for name, entry in models_read(config["models"], *names).items()
        }
        gains = config["controllers"][controller]
        chosen["controllers"] = {
            controller: {k: v for k, v in gains.items() if k not in PRESENTATION_KEYS}
        }
        return json.dumps(chosen, sort_keys=True)

    def write_export(self) -> str:
        """What exporting a network reads: how its Φ is compiled."""
        text = json.dumps(
            {"rollout": {"compile": self.config["rollout"]["compile"]}}, sort_keys=True
        )
        return write_job_file("export_network", text)

    def write_grid(self) -> str:
        """What cape.study.grid.study_grid reads, for `cape aggregate` to build the same grid:
        the study section, η, the number of draws and the controllers. In the config's order,
        not sorted: the studies' order decides which folder computes a shared run."""
        config = self.config
        text = json.dumps(
            {
                "study": config["study"],
                "disturbances": {"eta": config["disturbances"]["eta"]},
                "training": {"replicates": int(config["training"]["replicates"])},
                "controllers": config["controllers"],
            }
        )
        return write_job_file("aggregate", text)

    @staticmethod
    def write_parameters(job: str, **parameters: Any) -> str:
        """A notebook's parameters for papermill's ``-f``, each a string as ``-r`` would pass
        it (a list joined by commas), in the order given."""

        def text(value: Any) -> str:
            return ",".join(map(str, value)) if isinstance(value, (list, tuple)) else str(value)

        named = {name: text(value) for name, value in parameters.items()}
        return write_job_file(job, json.dumps(named, indent=1))
