"""The model stage for the rules: each model's trainings, which of them become its draws, and
what a draw and the model tables read (``TRAININGS`` in the rules).

A draw's choice depends on the trainings' health records, which the ``training_health``
checkpoint makes: ``health(model, seed)`` is that record's path through the checkpoint.
"""

from __future__ import annotations

import hashlib
import os
import shlex
from collections.abc import Callable, Iterable, Mapping
from contextlib import suppress
from dataclasses import dataclass
from typing import Any

from cape.errors import CapeError
from cape.layout import paths
from cape.specs.study import StudySpec
from cape.specs.training import TrainingSettings
from cape.training.draws import Choice, choose_training, deciding_cap, default_max_trainings
from cape.training.outcome import Outcome, read_outcome

Outputs = Callable[..., list[str]]
"""``outputs(rule, **wildcards)``: the files one job of a rule writes (Snakemake's rules)."""
Health = Callable[[str, int], str]
"""``health(model, seed)``: a training's health record, through the checkpoint."""


class _MissingRecordError(Exception):
    """A health record a draw asks for is neither made nor being read (``draw_inputs``)."""


def model_args(models: Iterable[str], replicate: int) -> str:
    """``--model NAME=DIR`` for each model's draw ``replicate``."""
    return " ".join(
        f"--model {shlex.quote(f'{m}={paths.model_dir(m, replicate)}')}" for m in models
    )


@dataclass(frozen=True)
class Trainings:
    """The configured models, the first training's seed, the cap on a model's trainings, the
    threads and checkpoint interval of a training and each model's epochs (the longest trains
    first), with Snakemake's ``outputs`` and ``health``."""

    models: tuple[str, ...]
    seed0: int
    max_trainings: int
    threads: int
    checkpoint_every: float
    """Seconds between a training's resumable checkpoints, as the config spells them."""
    epochs: Mapping[str, int]
    outputs: Outputs
    health: Health

    @classmethod
    def of(
        cls, study: StudySpec, training: TrainingSettings, outputs: Outputs, health: Health
    ) -> Trainings:
        cap = study.max_trainings
        return cls(
            models=tuple(study.models),
            seed0=int(training.seed),
            max_trainings=int(cap or default_max_trainings(study.replicates)),
            threads=int(training.threads),
            checkpoint_every=training.checkpoint_every,
            epochs={m: int(entry["train"]["epochs"]) for m, entry in study.models.items()},
            outputs=outputs,
            health=health,
        )

    def training_seed(self, k: int) -> int:
        """A model's k-th training has seed ``training.seed + k`` (SPEC §4)."""
        return self.seed0 + int(k)

    def training_priority(self, model: str) -> int:
        """The longest training first (EPM's 3000 epochs are the study's critical path), and
        every training before any rollout."""
        return 100 + self.epochs[model] // 10

    def draw_choice(self, wildcards: Any) -> Choice:
        """Which training draw r of a model is, asked for in the order of cape.training.draws
        (a training not yet checked is planned, and the draw waits for it)."""
        model = wildcards.model

        def outcome(k: int) -> Any:
            return read_outcome(self.health(model, self.training_seed(k)))

        return choose_training(int(wildcards.replicate), self.max_trainings, outcome)

    def draw_max_trainings(self, wildcards: Any) -> int:
        """The cap a draw is made under (cape.training.draws.deciding_cap); the configured one
        when a record it reads is no health record: the draw job then runs and `cape draw`
        says what is wrong in one line (its log), not the planner in a traceback."""
        try:
            choice = self.draw_choice(wildcards)
        except CapeError:
            return self.max_trainings
        return deciding_cap(choice, self.max_trainings)

    @staticmethod
    def draw_records(health: Iterable[str]) -> str:
        """The content of the health records a draw reads (its ``health`` inputs that exist),
        as a digest: a param of the draw rule, so a record changed in place re-decides the
        draw, whatever its file's time."""
        digest = hashlib.sha256()
        for path in health:
            if os.path.exists(path):
                with open(path, "rb") as record:
                    digest.update(hashlib.sha256(record.read()).digest())
        return digest.hexdigest()[:16]

    def draw_inputs(self, wildcards: Any) -> dict[str, Any]:
        """The trainings draw r of a model is chosen among: every consulted training's health
        record, weights, metadata and loss curve (`cape draw` checks each record against them),
        in seed order.

        A record the draw needs that is still to be made is Snakemake's checkpoint target
        while its file exists (Snakemake reads it when it updates the checkpoint's dependents),
        but a plain input once the file is missing: a job with a checkpoint target among its
        inputs is exempt from every rerun trigger of its own (its outputs' age, params, input
        set), so a draw whose record changed such that it now needs a training not yet made
        was left as it was ("Nothing to be done"); as a plain input the draw is rerun, and it is
        planned again when the record is made (Snakemake updates a checkpoint's dependents when
        it finishes)."""
        from snakemake.exceptions import IncompleteCheckpointException

        model = wildcards.model
        read: dict[int, str] = {}  # training index → its record, as the draw asked for them
        missing: list[str] = []

        def outcome(k: int) -> Outcome:
            try:
                record = self.health(model, self.training_seed(k))
            except IncompleteCheckpointException as pending:
                if os.path.exists(pending.targetfile):
                    raise
                missing.append(str(pending.targetfile))
                raise _MissingRecordError from None
            read[k] = record
            try:
                return read_outcome(record)
            except CapeError:  # `cape draw` refuses it in one line: the job runs to say so
                raise _MissingRecordError from None

        with suppress(_MissingRecordError):  # planned again once that record is made
            choose_training(int(wildcards.replicate), self.max_trainings, outcome)
        folders = [os.path.dirname(read[k]) for k in sorted(read)]  # seed order
        return {
            "health": [read[k] for k in sorted(read)] + missing,
            "weights": [f"{f}/{paths.WEIGHTS}" for f in folders],
            "meta": [f"{f}/{paths.META}" for f in folders],
            "losses": [f"{f}/{paths.LOSSES}" for f in folders],
        }

    def trained_models(self, replicate: int = 0) -> list[str]:
        """Weights, metadata and loss curve of every configured model's draw ``replicate``."""
        return [
            f"{paths.model_dir(m, replicate)}/{f}" for m in self.models for f in paths.MODEL_FILES
        ]

    def model_args(self, replicate: int = 0) -> str:
        """``--model NAME=DIR`` for every configured model's draw."""
        return model_args(self.models, replicate)

    def model_outputs(self, replicates: Iterable[int]) -> list[str]:
        """Every file of the model stage for these draws: each model's draw, exported network
        and frozen Φ, tables 1 and 4."""
        files: list[str] = []
        for r in replicates:
            for m in self.models:
                for stage in ("draw", "freeze", "export_network"):
                    files += self.outputs(stage, model=m, replicate=r)
            files += self.outputs("openloop_table", replicate=r)
            files += self.outputs("complexity_table", replicate=r)
        return files
