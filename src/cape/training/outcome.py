"""A training's outcome: its health record (``health.json``: did it pass the checks, why
not, its ETHZ validation RMSE, the weights it is about), read field by field and never trusted
(``Outcome.from_dict``, ``read_outcome``), and the failure rate over many (``reliability``).

What both the checks (``cape.training.health``, which decide an outcome) and the draws
(``cape.training.draws``, which choose among outcomes) read: neither imports the other for it.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cape.errors import CapeError

STATES = ("vx", "vy", "omega")
"""The components of a training's validation RMSE, as its health record names them."""

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
        """The record, sealed (``sha256`` over the rest: a hand edit is refused, not read)."""
        from cape.storage.integrity import sealed_record

        return sealed_record({
            "format": HEALTH_FORMAT,
            "seed": self.seed,
            "trained": self.trained,
            "reasons": list(self.reasons),
            "val_rmse": dict(self.val_rmse),
            "weights_sha256": self.weights_sha256,
        })  # fmt: skip

    @classmethod
    def from_dict(cls, record: Mapping[str, Any], where: str) -> Outcome:
        """The outcome a health record states, each field checked for its type (a string
        ``"no"`` is no verdict): ``CapeError`` naming the file and the field otherwise."""

        def refuse(problem: str) -> CapeError:
            return CapeError(
                f"{where}: not a training's health record ({problem}); rebuild it: delete it "
                "and rerun snakemake"
            )

        def field_of(name: str, kind: str, ok: Callable[[Any], bool]) -> Any:
            if name not in record:
                raise refuse(f"field {name!r} is missing")
            value = record[name]
            if not ok(value):
                raise refuse(f"field {name!r} is {shown(value)}, not {kind}")
            return value

        unknown = sorted(str(k) for k in record if k not in _FIELDS)
        if unknown:
            raise refuse(f"field {unknown[0]!r} is not one of a health record's")
        from cape.storage.integrity import check_record

        check_record(record, where, "rebuild it: delete it and rerun snakemake")
        field_of("format", f"{HEALTH_FORMAT}", lambda v: is_int(v) and v == HEALTH_FORMAT)
        seed = field_of("seed", "an integer", is_int)
        trained = field_of("trained", "true or false", lambda v: isinstance(v, bool))
        reasons = field_of(
            "reasons",
            "a list of strings",
            lambda v: isinstance(v, list) and all(isinstance(r, str) for r in v),
        )
        val_rmse = field_of(
            "val_rmse",
            "an object of a number (finite or not) for each of " + ", ".join(STATES),
            lambda v: (
                isinstance(v, dict)
                and sorted(v) == sorted(STATES)
                and all(_is_number(x) for x in v.values())
            ),
        )
        digest = field_of(
            "weights_sha256",
            "a SHA-256 digest (64 hexadecimal digits)",
            lambda v: isinstance(v, str) and _SHA256.fullmatch(v) is not None,
        )
        rmse = {str(k): float(v) for k, v in val_rmse.items()}
        return cls(seed, trained, tuple(reasons), rmse, digest)


_FIELDS = ("format", "seed", "trained", "reasons", "val_rmse", "weights_sha256", "sha256")
_SHA256 = re.compile(r"[0-9a-f]{64}")


def is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def shown(value: Any) -> str:
    """A JSON value as a user reads it in a message: its JSON type and text (short)."""
    kinds = {bool: "the boolean", str: "the string", int: "the integer", float: "the number",
             list: "a list", dict: "an object", type(None): "null"}  # fmt: skip
    kind = kinds.get(type(value), type(value).__name__)
    if value is None or isinstance(value, (list, dict)):
        return kind
    text = json.dumps(value)
    return f"{kind} {text[:40] + '…' if len(text) > 40 else text}"


class _RepeatedFieldError(Exception):
    pass


def _once(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object whose every key is given once (``json`` keeps the last of a repeated key:
    a record holding ``"trained"`` twice would say two things)."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _RepeatedFieldError(key)
        out[key] = value
    return out


def read_outcome(path: str | Path) -> Outcome:
    """The health record at ``path`` (``CapeError`` naming the file when it is not one)."""
    path = Path(path)
    try:
        record = json.loads(path.read_text(), object_pairs_hook=_once)
    except FileNotFoundError:
        raise CapeError(f"{path}: missing; `cape check-training` writes it") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CapeError(f"{path}: unreadable ({exc}); delete it and rerun snakemake") from None
    except _RepeatedFieldError as exc:
        raise CapeError(
            f"{path}: not a training's health record (field {exc.args[0]!r} is given twice); "
            "rebuild it: delete it and rerun snakemake"
        ) from None
    if not isinstance(record, dict):
        raise CapeError(f"{path}: not a training's health record (not a JSON object)")
    return Outcome.from_dict(record, str(path))


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
