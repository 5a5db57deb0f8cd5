"""Which trainings become a model's draws (SPEC §4, "a draw is a training that works").

A model's k-th training trains with seed ``training.seed + k``; draw r is its (r + 1)-th training
that passed the checks (``health.json``), in seed order. When ``max_trainings`` run out, the
remaining draws are its failed trainings in seed order, flagged ``trained: false``.
``choose_training`` asks for the outcomes it needs through a callback; draw r's first question
is training r. Details: docs/modules.md.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cape.errors import CapeError
from cape.layout import paths

HEALTH_FORMAT = 1


@dataclass(frozen=True)
class Outcome:
    """One training's health: its seed, whether it passed, the reasons it did not, its ETHZ
    validation one-step RMSE per component and the weights it is about."""

    seed: int
    trained: bool
    reasons: tuple[str, ...] = ()
    val_rmse: Mapping[str, float] = field(default_factory=dict)
    weights_sha256: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": HEALTH_FORMAT,
            "seed": self.seed,
            "trained": self.trained,
            "reasons": list(self.reasons),
            "val_rmse": dict(self.val_rmse),
            "weights_sha256": self.weights_sha256,
        }

    @classmethod
    def from_dict(cls, record: Mapping[str, Any], where: str) -> Outcome:
        try:
            if record.get("format") != HEALTH_FORMAT:
                raise ValueError(f"format {record.get('format')!r}, not {HEALTH_FORMAT}")
            return cls(
                int(record["seed"]),
                bool(record["trained"]),
                tuple(str(r) for r in record["reasons"]),
                {str(k): float(v) for k, v in record["val_rmse"].items()},
                str(record["weights_sha256"]),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise CapeError(
                f"{where}: not a training's health record ({exc}); rebuild it with "
                "`cape check-training` (snakemake does)"
            ) from None


def read_outcome(path: str | Path) -> Outcome:
    """The health record at ``path`` (``CapeError`` naming the file when it is not one)."""
    path = Path(path)
    try:
        record = json.loads(path.read_text())
    except FileNotFoundError:
        raise CapeError(f"{path}: missing; `cape check-training` writes it") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CapeError(f"{path}: unreadable ({exc}); delete it and rerun snakemake") from None
    if not isinstance(record, dict):
        raise CapeError(f"{path}: not a training's health record (not a JSON object)")
    return Outcome.from_dict(record, str(path))


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
class Reliability:
    """A recipe's reliability over the trainings tried: how many, how many failed, the failure
    rate and its Clopper–Pearson interval (``scipy.stats.binomtest``)."""

    tried: int
    failed: int
    rate: float
    low: float
    high: float


def reliability(outcomes: Sequence[Outcome], level: float = 0.95) -> Reliability:
    """The failure rate of ``outcomes`` with its exact ``level`` interval (NaN with none)."""
    tried = len(outcomes)
    failed = sum(not o.trained for o in outcomes)
    if not tried:
        return Reliability(0, 0, math.nan, math.nan, math.nan)
    from scipy.stats import binomtest

    ci = binomtest(failed, tried).proportion_ci(confidence_level=level, method="exact")
    return Reliability(tried, failed, failed / tried, float(ci.low), float(ci.high))


@dataclass(frozen=True)
class Draw:
    """Draw r of a model: which training it is (``choice``) and its folder's files by name
    (the training's weights and loss curve, its metadata with the draw recorded)."""

    choice: Choice
    files: Mapping[str, bytes]


def make_draw(model: str, replicate: int, max_trainings: int, trainings: Sequence[Path]) -> Draw:
    """Draw ``replicate`` of ``model`` from its ``trainings`` folders in seed order (SPEC §4):
    the (r + 1)-th that works, or the cap's stand-in; ``CapeError`` when a training it must
    consult is not given, or a folder's weights, metadata and health disagree."""
    from cape.models.trained import read_meta

    def outcome(k: int) -> Outcome:
        if k >= len(trainings):
            raise CapeError(
                f"draw {replicate} of {model} needs training {k}'s health, but only "
                f"{len(trainings)} --training folders were given"
            )
        return read_outcome(Path(trainings[k]) / paths.HEALTH)

    choice = choose_training(replicate, max_trainings, outcome)
    source = Path(trainings[choice.index])
    meta = read_meta(source)
    weights = (source / paths.WEIGHTS).read_bytes()
    digest = hashlib.sha256(weights).hexdigest()
    health = choice.consulted[choice.index]
    if meta.get("name") != model or digest != meta.get("weights_sha256"):
        raise CapeError(f"{source}: holds no {model} training whose weights match its meta.json")
    if health.weights_sha256 != digest:
        raise CapeError(
            f"{source}/{paths.HEALTH}: is about other weights than {source}/{paths.WEIGHTS}; "
            "delete it and rerun snakemake"
        )
    meta["replicate"] = replicate
    meta["draw"] = {
        "training": str(source),
        "index": choice.index,
        "trained": choice.trained,
        "cap_reached": choice.cap_reached,
        "max_trainings": max_trainings,
        "trainings": [o.to_dict() for o in choice.consulted],
    }
    files = {
        paths.WEIGHTS: weights,
        paths.LOSSES: (source / paths.LOSSES).read_bytes(),
        paths.META: (json.dumps(meta, indent=2, sort_keys=True) + "\n").encode(),
    }
    return Draw(choice, files)
