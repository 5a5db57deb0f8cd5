"""The closed-loop stage for the rules: the grid's runs, what each run and each controller's
solver reads, and their files (``RUNS`` in the rules)."""

from __future__ import annotations

import shlex
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

from cape.controllers import controller_class
from cape.layout import paths
from cape.layout.names import TRUTH, PlantName
from cape.layout.runs import RunId
from cape.specs.study import StudySpec
from cape.workflow.trainings import Outputs, model_args

RUN_FOLDER = str(RunId.wildcards().folder())
"""A run's folder, its log and its figure's stem, as the rules' wildcard patterns."""
RUN_LOG = str(RunId.wildcards().folder(paths.log("runs")))
RUN_STEM = RunId.wildcards().stem()


@dataclass(frozen=True)
class Runs:
    """The study (its controllers: which predict with an internal model, which compile their
    NLP), its grid (each run → the run that computes it: a shared run is computed once), the
    training data that bounds a learned plant and the reference's raceline."""

    study: StudySpec
    grid: Mapping[RunId, RunId]
    train_track: str
    raceline: str
    outputs: Outputs

    def uses_internal_model(self, controller: str) -> bool:
        """True for a controller that predicts with an internal model (the NMPCs)."""
        entry = self.study.controllers[controller]
        return bool(controller_class(controller, entry).needs_internal_model)

    def compiles_solver(self, controller: str) -> bool:
        """True for a controller whose NLP is compiled to C (built once by the solver rule)."""
        settings = self.study.controllers[controller].get("compile") or {}
        return self.uses_internal_model(controller) and bool(settings.get("enabled", False))

    @staticmethod
    def solver_path(controller: str, internal: str, replicate: int) -> str:
        """A controller's solver for an internal model of one draw (the true model's is draw
        0's for every draw: no trained network enters it)."""
        return paths.solver(controller, internal, 0 if internal == TRUTH else replicate)

    @staticmethod
    def model_inputs(role: str, name: str, replicate: int) -> dict[str, str]:
        """The files a plant or internal model ``name`` of draw ``replicate`` is read from: its
        exported network (a learned Φ) or frozen Φ, and its metadata; none for the truth."""
        plant = PlantName.parse(name)
        if plant.is_truth or plant.model is None:
            return {}
        folder = paths.model_dir(plant.model, replicate)
        inputs = {f"{role}_meta": f"{folder}/{paths.META}"}
        if plant.kind == "learned":
            inputs[f"{role}_network"] = f"{folder}/{paths.NETWORK}"
        else:
            inputs[f"{role}_frozen"] = f"{folder}/{paths.FROZEN_PHI}"
        return inputs

    def rollout_models(self, wildcards: Any) -> list[str]:
        """The plant and, for a controller with one, the internal model a run reads."""
        if self.uses_internal_model(wildcards.controller):
            return [wildcards.plant, wildcards.internal]
        return [wildcards.plant]

    def rollout_inputs(self, wildcards: Any) -> dict[str, str]:
        """What one run reads: the reference line, the plant's and internal model's files of
        the run's draw, and the controller's compiled solver for that internal model."""
        replicate = int(wildcards.replicate)
        inputs = {
            "raceline": self.raceline,
            **self.model_inputs("plant", wildcards.plant, replicate),
        }
        if wildcards.plant != TRUTH:  # its states bound a learned plant (SPEC §5.3)
            inputs["training_data"] = paths.dataset(self.train_track)
        if self.uses_internal_model(wildcards.controller):
            inputs.update(self.model_inputs("internal", wildcards.internal, replicate))
        if self.compiles_solver(wildcards.controller):
            inputs["solver"] = self.solver_path(wildcards.controller, wildcards.internal, replicate)
        return inputs

    def solver_inputs(self, wildcards: Any) -> dict[str, str]:
        """What building a controller's NLP reads: the reference line and the internal model."""
        internal = self.model_inputs("internal", wildcards.internal, int(wildcards.replicate))
        return {"raceline": self.raceline, **internal}

    def model_folder_args(self, wildcards: Any, names: Iterable[str]) -> str:
        """``--model NAME=DIR`` for each trained model the plants or internal models
        ``names`` read, of the rule's draw."""
        models = {m for name in names if (m := PlantName.parse(name).model) is not None}
        return model_args(sorted(models), int(wildcards.replicate))

    @staticmethod
    def training_data_arg(inputs: Any) -> str:
        """``--training-data PATH`` for a run whose plant is bounded by the training data."""
        if "training_data" not in inputs.keys():  # noqa: SIM118 (a Namedlist: `in` sees values)
            return ""
        return f"--training-data {shlex.quote(inputs.training_data)}"

    def computed_runs(self, replicates: Iterable[int] | None = None) -> list[RunId]:
        """The runs the grid computes (each once), of these draws (all: None)."""
        wanted = None if replicates is None else set(replicates)
        return list(
            dict.fromkeys(
                computed
                for run, computed in self.grid.items()
                if wanted is None or run.replicate in wanted
            )
        )

    def rollout_targets(self, replicates: Iterable[int] | None = None) -> list[str]:
        """metrics.json of every run the grid computes (each once), of these draws."""
        return [f"{run.folder()}/{paths.METRICS}" for run in self.computed_runs(replicates)]

    def run_outputs(self, runs: Iterable[RunId]) -> list[str]:
        """The files of every run in ``runs``, each once."""
        return [
            path for run in dict.fromkeys(runs) for path in self.outputs("rollout", **asdict(run))
        ]

    def solver_outputs(self, runs: Iterable[RunId]) -> list[str]:
        """The compiled solver of every run in ``runs`` that uses one."""
        return list(
            dict.fromkeys(
                self.solver_path(run.controller, run.internal, run.replicate)
                for run in runs
                if self.compiles_solver(run.controller)
            )
        )

    def example_series(self, study: str) -> list[str]:
        """The time series the η = 0 figures draw: every run of ``study`` at η = 0, first
        seed, draw 0 (the study's figures are draw 0's)."""
        return [
            f"{computed.folder()}/{paths.SERIES}"
            for run, computed in self.grid.items()
            if run.study == study and float(run.eta) == 0 and run.seed == 0 and run.replicate == 0
        ]
