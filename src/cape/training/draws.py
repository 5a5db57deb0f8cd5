"""Which trainings become a model's draws (SPEC §4, "a draw is a training that works").

A model's k-th training trains with seed ``training.seed + k``; draw r is its (r + 1)-th training
that passed the checks (``health.json``), in seed order. When ``max_trainings`` run out, the
remaining draws are its failed trainings in seed order, flagged ``trained: false``.
``choose_training`` asks for the outcomes it needs through a callback; draw r's first question
is training r. A record is checked, not trusted: read field by field for its type
(``Outcome.from_dict``), and ``make_draw`` decides each consulted training's verdict again from
the record's numbers and the training's files under the bar (``checked_outcome``). Details:
docs/modules.md.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cape.errors import CapeError
from cape.layout import paths
from cape.specs.training import HealthSettings
from cape.training.outcome import Outcome, is_int, read_outcome, shown


@dataclass(frozen=True)
class Choice:
    """Draw ``replicate``'s training: its index among the model's trainings, whether it
    passed, and the outcomes of every training consulted (index order)."""

    replicate: int
    index: int
    trained: bool
    consulted: tuple[Outcome, ...]
    cap_reached: bool


def default_max_trainings(replicates: int) -> int:
    """``training.max_trainings`` when the config leaves it unset: twice the draws."""
    return 2 * int(replicates)


def choose_training(
    replicate: int, max_trainings: int, outcome: Callable[[int], Outcome]
) -> Choice:
    """Draw ``replicate``'s training among at most ``max_trainings``, from ``outcome(k)``,
    the health of the model's k-th training (see the module docstring)."""
    if not 0 <= replicate < max_trainings:
        raise CapeError(
            f"draw {replicate}: needs at least {replicate + 1} trainings, but "
            f"training.max_trainings is {max_trainings}; raise it to at least training.replicates"
        )
    seen: dict[int, Outcome] = {}

    def ask(k: int) -> Outcome:
        if k not in seen:
            seen[k] = outcome(k)
        return seen[k]

    passed: list[int] = []
    failed: list[int] = []
    for k in range(max_trainings):
        earliest = k + (replicate - len(passed))  # this draw's, if every training from k passes
        if earliest < max_trainings:
            ask(earliest)
        (passed if ask(k).trained else failed).append(k)
        if len(passed) == replicate + 1:
            return Choice(replicate, k, True, _upto(seen, k), False)
    stand_in = failed[replicate - len(passed)]
    return Choice(replicate, stand_in, False, _upto(seen, max_trainings - 1), True)


def deciding_cap(choice: Choice, max_trainings: int) -> int:
    """The cap that decided ``choice``: ``max_trainings`` when the choice reached it, else the
    least cap that makes the same choice (its index + 1), so that a draw which found its
    training is the same draw under any larger cap (raising training.replicates, and with it
    the default cap, redoes none)."""
    return max_trainings if choice.cap_reached else choice.index + 1


def _upto(seen: Mapping[int, Outcome], last: int) -> tuple[Outcome, ...]:
    return tuple(seen[k] for k in range(last + 1))


@dataclass(frozen=True)
class Draw:
    """Draw r of a model: which training it is (``choice``) and its folder's files by name
    (the training's weights and loss curve, its metadata with the draw recorded)."""

    choice: Choice
    files: Mapping[str, bytes]


@dataclass(frozen=True)
class Training:
    """One ``--training`` folder of ``cape draw``: its metadata and its weights' digest."""

    folder: Path
    meta: Mapping[str, Any]
    weights_sha256: str

    @property
    def seed(self) -> int:
        return int(self.meta["seed"])


def given_trainings(model: str, folders: Sequence[Path]) -> list[Training]:
    """The ``folders`` of ``model``'s trainings as ``cape draw`` is given them, each read once:
    ``CapeError`` in one line for a folder that holds no ``model`` training whose weights
    match its meta.json, a training given twice (the same folder, or the same weights in
    another) and seeds not strictly increasing in the order given (draw r would be another
    training than the model's (r + 1)-th that works)."""
    from cape.models.trained import read_meta

    given: list[Training] = []
    for folder in map(Path, folders):
        if not folder.is_dir():
            raise CapeError(
                f"--training {folder}: no such folder; give the model's training folders "
                "(snakemake makes them under results/trainings/)"
            )
        meta = read_meta(folder)
        weights = folder / paths.WEIGHTS
        try:
            digest = hashlib.sha256(weights.read_bytes()).hexdigest()
        except OSError as exc:
            raise CapeError(
                f"{weights}: unreadable ({exc.strerror or exc}); train it again"
            ) from None
        if meta.get("name") != model or digest != meta.get("weights_sha256"):
            raise CapeError(
                f"{folder}: holds no {model} training whose weights match its meta.json"
            )
        if not is_int(meta.get("seed")):
            raise CapeError(
                f"{folder / paths.META}: field 'seed' is {shown(meta.get('seed'))}, not an "
                "integer; train it again (`snakemake --cores 2 --force "
                f"{folder / paths.WEIGHTS}`)"
            )
        training = Training(folder, meta, digest)
        for earlier in given:
            if earlier.folder.resolve() == folder.resolve():
                raise CapeError(
                    f"--training {folder}: given twice (also as --training {earlier.folder}); "
                    "give each of the model's trainings once, in seed order"
                )
            if earlier.weights_sha256 == digest:
                raise CapeError(
                    f"--training {folder}: holds the weights of --training {earlier.folder} "
                    f"(sha256 {digest[:12]}…); give each of the model's trainings once, in seed "
                    "order"
                )
        if given and training.seed <= given[-1].seed:
            raise CapeError(
                f"--training {folder}: seed {training.seed} does not follow seed "
                f"{given[-1].seed} of --training {given[-1].folder}; give the model's trainings "
                "in seed order (strictly increasing seeds)"
            )
        given.append(training)
    return given


def train_loss(folder: str | Path) -> list[float]:
    """The training loss per epoch of the training in ``folder`` (its loss.csv), as the
    health check reads it."""
    from cape.storage.io import read_csv

    again = f"train the model again (`snakemake --cores 2 --force {Path(folder) / paths.WEIGHTS}`)"
    losses = read_csv(
        Path(folder) / paths.LOSSES,
        "train the model first (snakemake does)",
        "not a loss curve ({reason}); " + again.replace("{", "{{").replace("}", "}}"),
    )
    if "train_loss" not in losses:
        raise CapeError(
            f"{Path(folder) / paths.LOSSES}: has no train_loss column; train the model again"
        )
    return [float(x) for x in losses["train_loss"].tolist()]


def checked_outcome(model: str, training: Training, settings: HealthSettings) -> Outcome:
    """The health record of ``training``, checked rather than trusted: about this training
    (its seed and weights) and with the verdict its own numbers give under the bar
    ``settings`` (``training.health``): its ETHZ validation RMSE and the folder's loss.csv
    through ``cape.training.health.training_checks`` again. ``CapeError`` in one line
    naming the record otherwise."""
    from cape.training.health import training_checks  # here: health's tables import pandas,

    # and the workflow imports this module (through the question's plan) in every process
    path = training.folder / paths.HEALTH
    outcome = read_outcome(path)
    if outcome.seed != training.seed:
        raise CapeError(
            f"{path}: is about seed {outcome.seed}, but {training.folder / paths.META} "
            f"trained seed {training.seed}; delete it and rerun snakemake"
        )
    if outcome.weights_sha256 != training.weights_sha256:
        raise CapeError(
            f"{path}: is about other weights than {training.folder / paths.WEIGHTS}; "
            "delete it and rerun snakemake"
        )
    reasons = tuple(training_checks(model, outcome.val_rmse, train_loss(training.folder), settings))
    if (outcome.trained, outcome.reasons) != (not reasons, reasons):
        raise CapeError(
            f"{path}: says {_verdict(outcome.trained, outcome.reasons)}, but its numbers and "
            f"{training.folder / paths.LOSSES} under training.health say "
            f"{_verdict(not reasons, reasons)}: its verdict does not follow from its numbers; "
            "delete it and rerun snakemake"
        )
    return outcome


def _verdict(trained: bool, reasons: Sequence[str]) -> str:
    said = "trained" if trained else "failed"
    return said + (f" ({'; '.join(reasons)})" if reasons else "")


def make_draw(
    model: str,
    replicate: int,
    max_trainings: int,
    trainings: Sequence[Path],
    settings: HealthSettings,
) -> Draw:
    """Draw ``replicate`` of ``model`` from its ``trainings`` folders in seed order (SPEC §4):
    the (r + 1)-th that works, or the cap's stand-in, under the health checks' ``settings``
    (``training.health``). Reads, never writes: ``CapeError`` for trainings given twice or
    out of seed order (``given_trainings``), when a training it must consult is not given,
    or a consulted training's record does not check out (``checked_outcome``)."""
    given = given_trainings(model, trainings)

    def outcome(k: int) -> Outcome:
        if k >= len(given):
            raise CapeError(
                f"draw {replicate} of {model} needs training {k}'s health, but only "
                f"{len(given)} --training folders were given"
            )
        return checked_outcome(model, given[k], settings)

    choice = choose_training(replicate, max_trainings, outcome)
    source = given[choice.index]
    meta = dict(source.meta)
    meta["replicate"] = replicate
    meta["draw"] = {
        "training": str(source.folder),
        "index": choice.index,
        "trained": choice.trained,
        "cap_reached": choice.cap_reached,
        "max_trainings": max_trainings,
        "trainings": [o.to_dict() for o in choice.consulted],
    }
    weights = (source.folder / paths.WEIGHTS).read_bytes()
    if hashlib.sha256(weights).hexdigest() != source.weights_sha256:
        raise CapeError(
            f"{source.folder / paths.WEIGHTS}: changed while the draw read it; run again"
        )
    files = {
        paths.WEIGHTS: weights,
        paths.LOSSES: (source.folder / paths.LOSSES).read_bytes(),
        paths.META: (json.dumps(meta, indent=2, sort_keys=True) + "\n").encode(),
    }
    return Draw(choice, files)
